"""Certified payoff lower bounds: no perturbation smaller than this hides a detection.

A payoff (attacks.py) is the norm of a perturbation an attack *found*; it is an
upper bound on the cheapest attack. This module computes, per N_dr window
``x0``, a radius ``r`` such that N_dr answers "vehicle" on every input ``x``
with ``||x - x0||_2 <= r`` (all m+1 channels, pixel scale [0, 1]). The attack's
threat model (perturbed inputs clipped to [0, 1]) is a subset of that ball, so
``r`` is a lower bound on every attack's payoff, DeepFool's and PGD's included.

Method: linear bound propagation (CROWN, Zhang et al. 2018, "Efficient Neural
Network Robustness Certification with General Activation Functions") through
our own layer types, the mean subtraction, convolutions, ReLUs, flatten and
linear layers:

- every pre-activation ``y`` gets bounds ``l <= y(x) <= u`` over the ball,
  layer by layer. An unstable ReLU (``l < 0 < u``) is replaced by two lines:
  above by the chord ``u/(u-l) (y - l)``, below by ``alpha y`` with ``alpha = 1``
  if ``u > -l`` else 0 (CROWN's adaptive choice);
- a bound on a neuron is a linear function of the input propagated backwards
  through those lines, ``y(x) >= a.x + c``, whose minimum over the L2 ball is
  ``a.x0 + c - eps ||a||_2`` (the dual norm). The mean subtraction is the
  projection ``P = I - 11^T/d``: ``||P a||^2 = ||a||^2 - (sum a)^2 / d``;
- convolutions are propagated in *local* form: a neuron's coefficients live
  in its receptive field only (a patch, plus its offset), so a conv-layer
  neuron costs its receptive field, not the whole window;
- a neuron whose interval bound (from the previous layer's bounds) is already
  of one sign is not propagated: its ReLU is exact;
- the final margin ``f = logit_vehicle - logit_none - logit(delta_dr)`` gets
  ``f(x) >= a.x + c`` with relaxations valid up to a radius ``R``; it stays
  positive up to ``r*(R) = (a.x0 + c) / ||P a||``, so ``min(R, r*(R))`` is
  certified. A search over ``R`` (bisection towards the fixed point
  ``r*(R) = R``) keeps the best; bounds computed at a larger ``R`` stay valid
  at smaller ones and are reused.

Everything runs batched over windows in float32 without autograd, with the
channels last (oneDNN's transposed convolutions run 2x faster that way on these small
patches), a neuron's lower and upper rows side by side so its relaxation is read
once (from the third convolution on, every channel of a position side by side:
``crown._crown_layer``); the final radius is reduced by ``SAFETY`` (relative) to absorb
float32 rounding (not a formally verified floating-point bound).

Here: a shipped CNN as a chain (:func:`chain_of`, :func:`detect_chain`) and the search
for the radius (:func:`certified_radius`, its settings :class:`CertifyConfig`, one
propagation :func:`ball_radius`). The layer bounds and the margin's bound are
lesmc/perception/crown.py's, the relaxations and the steps that pass a bound back one
layer lesmc/perception/relaxations.py's.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import torch
from torch import nn

from lesmc.perception.chain import Chain, Conv, Dense, Layer, centred, margin_of
from lesmc.perception.crown import (
    CHUNK_FLOATS,
    GROUPED_FROM,
    first_layer,
    interval_margin,
    layer_bounds,
    margin_form,
)
from lesmc.perception.heap import kept_heap
from lesmc.perception.relaxations import STACK, STACK_BELOW, Ball, Relax
from lesmc.perception.threads import all_torch_threads

#: This module's names, and those of the bound propagation it was split from (crown.py,
#: relaxations.py), still importable from here.
__all__ = [
    "CHUNK_FLOATS",
    "GROUPED_FROM",
    "SAFETY",
    "STACK",
    "STACK_BELOW",
    "START_MODEL",
    "START_MODEL_LEVELS",
    "START_MODEL_NET",
    "Ball",
    "Bounds",
    "CertifyConfig",
    "Relax",
    "ball_radius",
    "certified_radius",
    "chain_of",
    "detect_chain",
    "flip_distances",
    "interval_margin",
    "layer_bounds",
    "margin_form",
    "model_features",
    "quantile_radii",
    "start_model",
    "weights_digest",
]

SAFETY = 1e-3  #: relative reduction of every certified radius (float32 rounding)


def chain_of(net: nn.Module, t: float, subtract_mean: bool = True, detach: bool = True) -> Chain:
    """The Chain of an N_dr-like module (``features``: Conv2d/ReLU; ``head``: Flatten/Linear/ReLU).

    The last Linear (two logits) becomes the margin ``logit_1 - logit_0 - t``.
    ``DetectNet`` subtracts each window's mean first (``subtract_mean``).
    ``detach=False`` keeps the module's parameters, so bounds can be trained on
    (``interval_margin``).
    """

    def own(p: torch.Tensor) -> torch.Tensor:
        return (p.detach() if detach else p).float()

    hw: int | None = None
    layers: list[Layer] = []
    mods = list(getattr(net, "features", [])) + list(getattr(net, "head", []))
    relu_expected = False
    in_shape: tuple[int, int, int] | None = getattr(net, "in_shape", None)
    for mod in mods:
        if isinstance(mod, nn.ReLU):
            if not relu_expected:
                raise ValueError("ReLU must follow a convolution or a hidden linear layer")
            relu_expected = False
            continue
        if relu_expected:
            raise ValueError("every layer but the last must be followed by a ReLU")
        if isinstance(mod, nn.Conv2d):
            if hw is None:
                if in_shape is None:
                    raise ValueError("the first convolution needs net.in_shape or a 21x21 input")
                hw = in_shape[1]
            conv = _conv_layer(mod, hw, own)
            layers.append(conv)
            hw = conv.out_hw
            relu_expected = True
        elif isinstance(mod, nn.Linear):
            if mod.bias is None:
                raise ValueError("linear layers need a bias")
            layers.append(Dense(own(mod.weight), own(mod.bias)))
            relu_expected = True
        elif not isinstance(mod, nn.Flatten):
            raise ValueError(f"unsupported layer {mod}")
    last = layers[-1] if layers else None
    if not isinstance(last, Dense) or last.weight.shape[0] != 2:
        raise ValueError("the network must end in a linear layer with two logits")
    w, b = last.weight, last.bias
    layers[-1] = Dense((w[1] - w[0])[None], (b[1] - b[0] - t)[None])
    if in_shape is None:
        raise ValueError("net.in_shape is needed")
    return Chain(in_shape, subtract_mean, tuple(layers))


def _conv_layer(mod: nn.Conv2d, hw: int, own: Callable[[torch.Tensor], torch.Tensor]) -> Conv:
    """A Conv2d of square kernel, stride and zero padding, with a bias, reading hw x hw maps."""
    k, s, p = mod.kernel_size, mod.stride, mod.padding
    if (
        not isinstance(p, tuple)
        or k[0] != k[1]
        or s[0] != s[1]
        or p[0] != p[1]
        or mod.dilation != (1, 1)
        or mod.groups != 1
        or mod.bias is None
        or mod.padding_mode != "zeros"
    ):
        raise ValueError(f"unsupported convolution {mod}")
    out = (hw + 2 * p[0] - k[0]) // s[0] + 1
    return Conv(own(mod.weight), own(mod.bias), s[0], p[0], hw, out)


def detect_chain(net: nn.Module, t: float, detach: bool = True) -> Chain:
    """The Chain of the shipped ``DetectNet`` (21x21 windows, mean subtracted)."""
    from lesmc.perception.cnn import DR_SIZE

    first = net.get_submodule("features.0")
    assert isinstance(first, nn.Conv2d)
    c_in = first.in_channels
    net.in_shape = (c_in, DR_SIZE, DR_SIZE)  # type: ignore[assignment]
    try:
        return chain_of(net, t, subtract_mean=True, detach=detach)
    finally:
        del net.in_shape


# ---------------------------------------------------------------- radius search

#: The first ball of a window with an attack payoff, on the shipped N_dr: log(R / r0) =
#: c0 + c1 log(r0 / payoff) + c2 log(r_near / r0) + c3 log(r_far / r0), where r0, r_near
#: and r_far are the 0.25, 0.17 and 0.33 quantiles of the flip distances (r0 at most
#: ``seed`` x payoff). Least squares on where CROWN stops certifying (the geometric middle
#: of the largest radius on a grid of 13 that certified and the next), for 300 windows of
#: the default video disjoint from bench_certify's (residual 0.077 in log, 0.085 on
#: bench_certify's own); c0 lowered by log(0.88) so that about 19 balls in 20 certify at
#: once (benchmarks/exp_certify_start.py; docs/performance.md, "Issue 31, sixteenth round").
START_MODEL = (-0.6849, -0.2705, 0.2526, 0.0784)
#: The network START_MODEL was fitted on, the shipped N_dr (:func:`weights_digest`), and
#: the quantile settings (level, spread) of its features: anything else starts from the
#: quantile rule.
START_MODEL_NET = "9890da1b2b7167c407dfd0cbf29049cf4e6f6dec252e1539128a95b91b38ab46"
START_MODEL_LEVELS = (0.25, 0.08)


@dataclass(frozen=True)
class CertifyConfig:
    """Settings of the radius search (docs/cnn.md, "Certified lower bounds")."""

    steps: int = 2  #: bound propagations per window
    level: float = 0.25  #: first radius: where this fraction of first-layer ReLUs is unstable
    spread: float = 0.08  #: change of that fraction after the first propagation
    seed: float = 0.5  #: ... but at most this fraction of the upper bracket (attack payoff)
    batch: int = 32  #: windows propagated together
    give_up: float = 0.7  #: unstable fraction of a layer beyond which a ball is abandoned
    #: a ball that certified is grown only when its margin bound's slack r*(R) / R is at
    #: least this: on N_dr the next ball's bound collapsed whenever it was below about 15
    grow_slack: float = 16.0
    #: where the first ball of a window with a payoff goes: "auto", the payoff model
    #: (:data:`START_MODEL`) for the network it was fitted on and the quantile rule for any
    #: other; "quantile", the quantile rule always
    start: Literal["auto", "quantile"] = "auto"
    #: coefficients of a payoff model of one's own (any network; overrides ``start``)
    start_model: tuple[float, float, float, float] | None = None
    #: the factor a payoff model's first ball is grown or shrunk by (its error is about 8%)
    model_step: float = 1.2
    #: ``grow_slack`` for those balls: grown from a slack of 16-24 they nearly always failed
    model_slack: float = 24.0


def weights_digest(chain: Chain) -> str:
    """sha256 of a chain's shape and float32 weights, the margin's offset (which holds the
    decision threshold) left out: the same network whatever file it came from."""
    h = hashlib.sha256(repr((chain.in_shape, chain.subtract_mean)).encode())
    for i, layer in enumerate(chain.layers):
        if isinstance(layer, Conv):
            h.update(repr(("conv", layer.stride, layer.padding, layer.in_hw)).encode())
        tensors = [layer.weight] if i + 1 == len(chain.layers) else [layer.weight, layer.bias]
        for t in tensors:
            h.update(repr(tuple(t.shape)).encode())
            h.update(t.detach().float().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def start_model(chain: Chain, cfg: CertifyConfig) -> tuple[float, float, float, float] | None:
    """The payoff model that places ``chain``'s first balls under ``cfg``: one's own, else
    :data:`START_MODEL` where ``cfg.start`` is "auto" and the network and quantile settings
    are the ones it was fitted on, else none (the quantile rule)."""
    if cfg.start_model is not None:
        return cfg.start_model
    fitted = (cfg.level, cfg.spread) == START_MODEL_LEVELS
    if cfg.start == "auto" and fitted and weights_digest(chain) == START_MODEL_NET:
        return START_MODEL
    return None


def certified_radius(
    chain: Chain,
    windows: np.ndarray,
    upper: np.ndarray | None = None,
    cfg: CertifyConfig | None = None,
    on_batch: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Per window, an L2 radius within which the margin stays positive (0 when it is not).

    ``upper``: a known flipping radius per window (the attack's payoff, ``inf``
    when none): the search stays below it. It only steers the search; every
    returned radius is certified on its own. ``on_batch(done)`` after each batch
    of ``cfg.batch`` windows (progress, budgets).
    """
    cfg = cfg or CertifyConfig()
    cfg = replace(cfg, start_model=start_model(chain, cfg))
    n = len(windows)
    out = np.zeros(n)
    with torch.inference_mode(), all_torch_threads(), kept_heap():
        for a in range(0, n, cfg.batch):
            x = torch.from_numpy(np.ascontiguousarray(windows[a : a + cfg.batch], np.float32))
            up = None if upper is None else np.asarray(upper[a : a + cfg.batch], float)
            out[a : a + len(x)] = _search(chain, x, up, cfg)
            if on_batch is not None:
                on_batch(a + len(x))
    return out


def flip_distances(chain: Chain, z0: torch.Tensor) -> torch.Tensor:
    """(B, n): each first-layer neuron's L2 distance to its hinge (exact: the layer is linear).

    A ball of radius r makes exactly the neurons with distance < r unstable;
    its quantiles put the radius search on a per-window scale.
    """
    lo, hi = first_layer(chain, Ball(z0, torch.ones(len(z0)), _dim(chain), chain.subtract_mean))
    mid, rad = (lo + hi) / 2, (hi - lo) / 2
    dist = torch.where(rad > 0, mid.abs() / rad.clamp(min=1e-30), torch.full_like(mid, math.inf))
    return dist.flatten(1)


def _dim(chain: Chain) -> int:
    return math.prod(chain.in_shape)


def _search(
    chain: Chain, x: torch.Tensor, upper: np.ndarray | None, cfg: CertifyConfig
) -> np.ndarray:
    """Geometric bisection on R from a per-window start; keeps the best min(R, r*(R)).

    The start (:func:`_start`) is the ``cfg.level``-quantile of the first layer's flip
    distances (the radius making that fraction of its ReLUs unstable), and the steps
    until a bracket is found are the ratios to the ``level -+ spread`` quantiles (at
    least 1.5x down): a window's CROWN bound collapses once too many of its ReLUs are
    unstable, at about the same fraction for every window (docs/cnn.md), while the
    radius varies 20x. A window with an attack payoff starts where a payoff model
    puts it instead (:func:`start_model`), stepped by ``cfg.model_step``: on the shipped
    N_dr about 19 first balls in 20 then certify, so most windows need one propagation.
    A ball that certified is grown only when the margin's bound has slack,
    ``r*(R) >= cfg.grow_slack * R`` (``cfg.model_slack`` from a payoff model's ball): from
    the quantile rule's, on 128 of the default video's windows no grown ball certified
    from a slack below 14.6, and 63 of the 79 that failed had less than 16; from the
    payoff model's, balls grown from 16-24 nearly always failed. That propagation is not
    spent.
    """
    nb = len(x)
    z0 = centred(chain, x)
    f0 = margin_of(chain, x)
    r, grow, shrink, cap, slack_at = _start(chain, z0, upper, cfg)
    best = torch.zeros(nb, dtype=torch.float64)
    r_ok = torch.zeros(nb, dtype=torch.float64)
    r_bad = torch.full((nb,), math.inf, dtype=torch.float64)
    live = f0 > 0
    # bounds of the smallest ball that failed so far: valid for every smaller ball
    prior: Bounds | None = None
    for _ in range(cfg.steps):
        if not bool(live.any()):
            break
        idx = live.nonzero().ravel()
        ri = r[idx]
        ball = Ball(z0[idx], ri.float(), _dim(chain), chain.subtract_mean)
        pri = None if prior is None else _prior_for(prior, idx, ri <= r_bad[idx])
        rstar, bounds = ball_radius(chain, ball, pri, cfg.give_up)
        # a NaN (flip distances all infinite: zero filters) certifies nothing
        best[idx] = torch.maximum(best[idx], torch.nan_to_num(torch.minimum(ri, rstar), nan=0.0))
        ok = rstar >= ri
        r_ok[idx] = torch.where(ok, torch.maximum(r_ok[idx], ri), r_ok[idx])
        failed = ~ok
        if bool(failed.any()):
            prior = _keep_failed(prior, bounds, idx, failed, nb)
            r_bad[idx[failed]] = ri[failed]
        lo, hi = r_ok[idx], r_bad[idx]
        step = torch.where(ok, ri * grow[idx], ri / shrink[idx])
        bracketed = (lo > 0) & torch.isfinite(hi)
        r[idx] = torch.minimum(torch.where(bracketed, torch.sqrt(lo * hi), step), cap[idx])
        slack = ok & (rstar < slack_at[idx] * ri)  # grown, it would collapse (docstring)
        live[idx] = ~(ok & (ri >= cap[idx])) & ~(bracketed & (hi - lo <= 0.02 * hi)) & ~slack
    result: np.ndarray = (best * (1 - SAFETY)).numpy()
    return result


Bounds = list[tuple[torch.Tensor, torch.Tensor]]


def ball_radius(
    chain: Chain, ball: Ball, prior: Bounds | None = None, give_up: float = 1.0
) -> tuple[torch.Tensor, Bounds]:
    """One propagation over the balls: r*(R) per window (float64), the radius up to which
    the margin's linear bound stays positive (0 where it is not positive at the centre;
    ``min(R, r*(R))`` is certified), and the layer bounds (:func:`layer_bounds`)."""
    bounds, relaxes = layer_bounds(chain, ball, prior, give_up)
    value, norm = margin_form(chain, ball, relaxes)
    value, norm = value.double(), norm.double()
    rstar = torch.where(value > 0, value / norm.clamp(min=1e-30), torch.zeros_like(value))
    return rstar, bounds


def _prior_for(prior: Bounds, idx: torch.Tensor, inside: torch.Tensor) -> Bounds:
    """The kept bounds of windows ``idx``, for those whose ball lies ``inside`` the one that
    failed (a larger ball's bounds hold in a smaller one); none elsewhere."""
    return [
        (_where(inside, pl[idx], -math.inf), _where(inside, pu[idx], math.inf)) for pl, pu in prior
    ]


def _keep_failed(
    prior: Bounds | None, bounds: Bounds, idx: torch.Tensor, failed: torch.Tensor, nb: int
) -> Bounds:
    """Keep the layer bounds of the windows whose ball just failed: the smallest failing
    ball's bounds are valid for every smaller ball tried later."""
    if prior is None:
        prior = [
            (torch.full((nb, *bl.shape[1:]), -math.inf), torch.full((nb, *bl.shape[1:]), math.inf))
            for bl, _ in bounds
        ]
    fidx = idx[failed]
    for (pl, pu), (bl, bu) in zip(prior, bounds, strict=True):
        pl[fidx], pu[fidx] = bl[failed], bu[failed]
    return prior


def _start(
    chain: Chain, z0: torch.Tensor, upper: np.ndarray | None, cfg: CertifyConfig
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per window: the first radius, the factors to grow and shrink it by until a bracket
    is found, the cap (the attack's payoff) and the slack a certified ball needs to grow.

    The quantile rule: the ``cfg.level``-quantile r0 of the first layer's flip distances,
    at most ``cfg.seed`` times the payoff, stepped by the ratios to the ``level -+
    spread`` quantiles. A window with a payoff, given ``cfg.start_model``, starts where
    that model puts it (:func:`_model_start`), stepped by ``cfg.model_step``."""
    nb = len(z0)
    nearer, start, further = quantile_radii(chain, z0, cfg)
    grow = (further / start).clamp(min=1.05)
    shrink = (start / nearer).clamp(min=1.5)
    cap = torch.full((nb,), math.inf, dtype=torch.float64)
    if upper is not None:
        u = torch.from_numpy(upper)
        cap = torch.where(torch.isfinite(u) & (u > 0), u, cap)
    r = torch.minimum(start, cfg.seed * cap)
    slack = torch.full_like(r, cfg.grow_slack)
    if cfg.start_model is None:
        return r, grow, shrink, cap, slack
    guess = _model_start(cfg.start_model, r, nearer, further, cap)
    paid = torch.isfinite(cap) & torch.isfinite(guess) & (guess > 0)
    guess = torch.minimum(guess, cfg.seed * cap)
    step = torch.full_like(r, cfg.model_step)
    return (
        torch.where(paid, guess, r),
        torch.where(paid, step, grow),
        torch.where(paid, step, shrink),
        cap,
        torch.where(paid, torch.full_like(r, cfg.model_slack), slack),
    )


def quantile_radii(
    chain: Chain, z0: torch.Tensor, cfg: CertifyConfig
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per window, the ``level - spread``, ``level`` and ``level + spread`` quantiles of the
    first layer's flip distances (float64, at least 1e-6): the quantile rule's radii."""
    dist = flip_distances(chain, z0).double()
    levels = [max(cfg.level - cfg.spread, 0.0), cfg.level, min(cfg.level + cfg.spread, 1.0)]
    nearer, start, further = torch.quantile(
        dist, torch.tensor(levels, dtype=torch.float64), dim=1
    ).clamp(min=1e-6)
    return nearer, start, further


def model_features(
    r0: torch.Tensor, nearer: torch.Tensor, further: torch.Tensor, payoff: torch.Tensor
) -> torch.Tensor:
    """(4, B): a payoff model's features (1, log r0/payoff, log near/r0, log far/r0), r0 the
    quantile rule's first radius (:data:`START_MODEL`); not finite where an input is not."""
    log_r0 = r0.log()
    return torch.stack(
        [torch.ones_like(r0), log_r0 - payoff.log(), nearer.log() - log_r0, further.log() - log_r0]
    )


def _model_start(
    coef: tuple[float, float, float, float],
    r0: torch.Tensor,
    nearer: torch.Tensor,
    further: torch.Tensor,
    payoff: torch.Tensor,
) -> torch.Tensor:
    """A payoff model's first radius: r0 exp(c . :func:`model_features`)."""
    features = model_features(r0, nearer, further, payoff)
    return r0 * torch.exp(torch.tensordot(torch.tensor(coef, dtype=r0.dtype), features, dims=1))


def _where(keep: torch.Tensor, t: torch.Tensor, other: float) -> torch.Tensor:
    return torch.where(keep.view(-1, *[1] * (t.dim() - 1)), t, torch.full_like(t, other))
