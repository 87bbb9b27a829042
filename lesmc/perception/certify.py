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

Everything runs batched over windows in float32 without autograd; the final
radius is reduced by ``SAFETY`` (relative) to absorb float32 rounding (not a
formally verified floating-point bound).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

SAFETY = 1e-3  #: relative reduction of every certified radius (float32 rounding)
CHUNK_FLOATS = 1 << 23  #: coefficients in flight per propagation chunk (32 MiB of float32)


@dataclass(frozen=True)
class Conv:
    """A convolution ``y = conv(h) + b`` (square kernel), followed by a ReLU."""

    weight: torch.Tensor  # (out, in, k, k)
    bias: torch.Tensor  # (out,)
    stride: int
    padding: int
    in_hw: int
    out_hw: int


@dataclass(frozen=True)
class Dense:
    """A linear layer ``y = W h + b``; hidden ones are followed by a ReLU."""

    weight: torch.Tensor  # (out, in)
    bias: torch.Tensor  # (out,)


Layer = Conv | Dense


@dataclass(frozen=True)
class Chain:
    """A network as our bound propagation sees it.

    ``x -> [x - mean(x)] -> conv, ReLU, ... -> flatten -> dense, ReLU, ... -> margin``;
    the last Dense has one output, the decision margin (> 0: "vehicle").
    """

    in_shape: tuple[int, int, int]
    subtract_mean: bool
    layers: tuple[Layer, ...]


def chain_of(net: nn.Module, t: float, subtract_mean: bool = True) -> Chain:
    """The Chain of an N_dr-like module (``features``: Conv2d/ReLU; ``head``: Flatten/Linear/ReLU).

    The last Linear (two logits) becomes the margin ``logit_1 - logit_0 - t``.
    ``DetectNet`` subtracts each window's mean first (``subtract_mean``).
    """
    channels: int | None = None
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
            if hw is None:
                if in_shape is None:
                    raise ValueError("the first convolution needs net.in_shape or a 21x21 input")
                hw = in_shape[1]
            out = (hw + 2 * p[0] - k[0]) // s[0] + 1
            layers.append(
                Conv(mod.weight.detach().float(), mod.bias.detach().float(), s[0], p[0], hw, out)
            )
            hw, channels = out, mod.out_channels
            relu_expected = True
        elif isinstance(mod, nn.Linear):
            if mod.bias is None:
                raise ValueError("linear layers need a bias")
            layers.append(Dense(mod.weight.detach().float(), mod.bias.detach().float()))
            relu_expected = True
        elif not isinstance(mod, nn.Flatten):
            raise ValueError(f"unsupported layer {mod}")
    last = layers[-1] if layers else None
    if not isinstance(last, Dense) or last.weight.shape[0] != 2:
        raise ValueError("the network must end in a linear layer with two logits")
    w, b = last.weight, last.bias
    layers[-1] = Dense((w[1] - w[0])[None], (b[1] - b[0] - t)[None])
    del channels
    if in_shape is None:
        raise ValueError("net.in_shape is needed")
    return Chain(in_shape, subtract_mean, tuple(layers))


def detect_chain(net: nn.Module, t: float) -> Chain:
    """The Chain of the shipped ``DetectNet`` (21x21 windows, mean subtracted)."""
    from lesmc.perception.cnn import DR_SIZE

    first = net.get_submodule("features.0")
    assert isinstance(first, nn.Conv2d)
    c_in = first.in_channels
    net.in_shape = (c_in, DR_SIZE, DR_SIZE)  # type: ignore[assignment]
    try:
        return chain_of(net, t, subtract_mean=True)
    finally:
        del net.in_shape


# ---------------------------------------------------------------- forward pass


def margin_of(chain: Chain, x: torch.Tensor) -> torch.Tensor:
    """The margin of ``chain`` on a batch (B, C, H, W): the network's own forward pass."""
    h = _centre(chain, x)
    for i, layer in enumerate(chain.layers):
        h = _affine(layer, h)
        if i + 1 < len(chain.layers):
            h = torch.relu(h)
    return h[:, 0]


def _centre(chain: Chain, x: torch.Tensor) -> torch.Tensor:
    return x - x.mean(dim=(1, 2, 3), keepdim=True) if chain.subtract_mean else x


def _affine(layer: Layer, h: torch.Tensor) -> torch.Tensor:
    if isinstance(layer, Conv):
        return F.conv2d(h, layer.weight, layer.bias, layer.stride, layer.padding)
    return F.linear(h.flatten(1), layer.weight, layer.bias)


def _affine_abs(layer: Layer, r: torch.Tensor) -> torch.Tensor:
    if isinstance(layer, Conv):
        return F.conv2d(r, layer.weight.abs(), None, layer.stride, layer.padding)
    return F.linear(r.flatten(1), layer.weight.abs())


# ---------------------------------------------------------------- relaxations


@dataclass
class Relax:
    """Per window and neuron, the lines replacing ReLU(y) on [l, u].

    Lower line ``lo * y``; upper line ``up * y + cut``. Stacked (B, 3, *shape).
    """

    maps: torch.Tensor

    @staticmethod
    def of(lower: torch.Tensor, upper: torch.Tensor) -> Relax:
        active = lower >= 0
        unstable = (lower < 0) & (upper > 0)
        den = torch.where(unstable, upper - lower, torch.ones_like(upper))
        up = torch.where(unstable, upper / den, active.to(upper.dtype))
        cut = torch.where(unstable, -lower * upper / den, torch.zeros_like(upper))
        lo = torch.where(unstable, (upper > -lower).to(upper.dtype), active.to(upper.dtype))
        return Relax(torch.stack([lo, up, cut], dim=1))


@dataclass
class Coeffs:
    """Linear lower bounds under construction: ``sum A * h + const`` for G rows of S specs.

    For a conv level, ``a`` is (G, S, C, r, r), a patch whose top-left pixel is
    ``offset`` (G, 2) (row, column; may lie outside the layer: padding). For a
    dense level, ``a`` is (G, S, n) and ``offset`` is unused. ``win`` (G,) is
    each row's window.
    """

    a: torch.Tensor
    offset: torch.Tensor
    win: torch.Tensor
    const: torch.Tensor


def _patches(maps: torch.Tensor, win: torch.Tensor, offset: torch.Tensor, r: int) -> torch.Tensor:
    """Patches (G, M, r, r) of ``maps`` (B, M, H, W) at ``offset``, zero outside the layer."""
    _, m, h, w = maps.shape
    lo = int(offset.min())
    hi = int(offset.max()) + r
    q = max(0, -lo, hi - min(h, w))
    padded = F.pad(maps, (q, q, q, q)).permute(0, 2, 3, 1).reshape(-1, m)
    hp, wp = h + 2 * q, w + 2 * q
    d = torch.arange(r, device=maps.device)
    rows = offset[:, 0, None] + q + d  # (G, r)
    cols = offset[:, 1, None] + q + d
    idx = win[:, None, None] * (hp * wp) + rows[:, :, None] * wp + cols[:, None, :]
    return padded[idx].permute(0, 3, 1, 2)


def _through_relu(c: Coeffs, relax: Relax) -> Coeffs:
    """Coefficients on h = ReLU(y) -> on y (lower bounds: A+ takes the lower line)."""
    if c.a.dim() == 5:
        m = _patches(relax.maps.flatten(1, 2), c.win, c.offset, c.a.shape[-1])
        m = m.reshape(len(m), 3, -1, *m.shape[2:])[:, None]  # (G, 1, 3, C, r, r)
    else:
        m = relax.maps[c.win][:, None]  # (G, 1, 3, n)
    pos, neg = c.a.clamp(min=0), c.a.clamp(max=0)
    a = pos * m[:, :, 0] + neg * m[:, :, 1]
    const = c.const + (neg * m[:, :, 2]).flatten(2).sum(-1)
    return Coeffs(a, c.offset, c.win, const)


def _through_affine(c: Coeffs, layer: Layer, below: tuple[int, int, int] | None) -> Coeffs:
    """Coefficients on y = layer(h) -> on h. ``below``: h's (C, H, W) when it is a conv level."""
    a = c.a
    g, s = a.shape[:2]
    if isinstance(layer, Conv):
        const = c.const + (a.sum(dim=(-2, -1)) * layer.bias).sum(-1)
        r = a.shape[-1]
        out = F.conv_transpose2d(a.reshape(g * s, *a.shape[2:]), layer.weight, stride=layer.stride)
        k = (r - 1) * layer.stride + layer.weight.shape[-1]
        offset = c.offset * layer.stride - layer.padding
        return Coeffs(out.reshape(g, s, -1, k, k), offset, c.win, const)
    const = c.const + a @ layer.bias
    a = a @ layer.weight
    if below is not None:  # flatten: a conv level, the whole layer as one patch
        ch, hh, ww = below
        side = max(hh, ww)
        a = a.reshape(g, s, ch, hh, ww)
        if hh != ww:
            a = F.pad(a, (0, side - ww, 0, side - hh))
        return Coeffs(a, torch.zeros(g, 2, dtype=torch.long), c.win, const)
    return Coeffs(a, c.offset, c.win, const)


@dataclass
class Ball:
    """The windows' centres (mean removed when the chain does) and radii."""

    z0: torch.Tensor  # (B, C, H, W)
    eps: torch.Tensor  # (B,)
    d: int  # input dimension
    subtract_mean: bool


def _concretise(c: Coeffs, ball: Ball) -> tuple[torch.Tensor, torch.Tensor]:
    """(a.x0 + c, ||P a||_2) per row and spec for coefficients on the input."""
    if c.a.dim() == 5:
        r = c.a.shape[-1]
        inside = torch.ones_like(ball.z0[:1, :1]).expand(len(ball.z0), 1, -1, -1)
        maps = torch.cat([ball.z0, inside], dim=1)
        m = _patches(maps, c.win, c.offset, r)[:, None]  # (G, 1, C+1, r, r)
        a = c.a * m[:, :, -1:]
        z = m[:, :, :-1]
    else:
        a = c.a
        z = ball.z0.flatten(1)[c.win][:, None]
    value = (a * z).flatten(2).sum(-1) + c.const
    sq = a.square().flatten(2).sum(-1)
    if ball.subtract_mean:
        sq = sq - a.flatten(2).sum(-1).square() / ball.d
    return value, sq.clamp(min=0).sqrt()


# ---------------------------------------------------------------- layer bounds


def _shape(chain: Chain, i: int) -> tuple[int, ...]:
    layer = chain.layers[i]
    if isinstance(layer, Conv):
        return (layer.weight.shape[0], layer.out_hw, layer.out_hw)
    return (layer.weight.shape[0],)


def _level_shape(chain: Chain, i: int) -> tuple[int, int, int] | None:
    """(C, H, W) of the input of layer ``i`` when it is a conv level (h_{i-1}, or x for i = 0)."""
    if i == 0:
        return chain.in_shape
    prev = chain.layers[i - 1]
    if isinstance(prev, Conv):
        return (prev.weight.shape[0], prev.out_hw, prev.out_hw)
    return None


def _backward(
    chain: Chain, i: int, c: Coeffs, relaxes: list[Relax], ball: Ball
) -> tuple[torch.Tensor, torch.Tensor]:
    """Coefficients on the input of layer ``i`` -> (value at x0, dual norm) per row and spec."""
    for j in range(i - 1, -1, -1):
        c = _through_relu(c, relaxes[j])
        c = _through_affine(c, chain.layers[j], _level_shape(chain, j))
    return _concretise(c, ball)


def _start(chain: Chain, i: int, win: torch.Tensor, neuron: torch.Tensor, signs: int) -> Coeffs:
    """Rows of layer ``i``'s weights for the selected neurons (flat index), ``+W`` [and ``-W``]."""
    layer = chain.layers[i]
    sgn = torch.tensor([1.0, -1.0][:signs])
    if isinstance(layer, Conv):
        per = layer.out_hw * layer.out_hw
        ch, pos = neuron // per, neuron % per
        offset = torch.stack([pos // layer.out_hw, pos % layer.out_hw], 1)
        offset = offset * layer.stride - layer.padding
        a = layer.weight[ch][:, None] * sgn.view(1, -1, 1, 1, 1)
        const = layer.bias[ch][:, None] * sgn
        return Coeffs(a, offset, win, const)
    a = layer.weight[neuron][:, None] * sgn.view(1, -1, 1)
    const = layer.bias[neuron][:, None] * sgn
    below = _level_shape(chain, i)
    if below is not None:  # first dense layer after the convolutions (or on the input)
        a = a.reshape(len(neuron), signs, *below)
    return Coeffs(a, torch.zeros(len(neuron), 2, dtype=torch.long), win, const)


def _patch_floats(chain: Chain, i: int) -> int:
    """Largest number of coefficients one spec row carries while propagating from layer ``i``."""
    layer = chain.layers[i]
    below = _level_shape(chain, i)
    if isinstance(layer, Conv):
        r = layer.weight.shape[-1]
        most = layer.weight.shape[1] * r * r
    elif below is not None:
        r = max(below[1], below[2])
        most = below[0] * r * r
    else:
        r = 0
        most = layer.weight.shape[1]
    for j in range(i - 1, -1, -1):
        lj = chain.layers[j]
        if isinstance(lj, Conv):
            r = (r - 1) * lj.stride + lj.weight.shape[-1]
            most = max(most, lj.weight.shape[1] * r * r)
        else:
            nb = _level_shape(chain, j)
            if nb is not None:
                r = max(nb[1], nb[2])
                most = max(most, nb[0] * r * r)
            else:
                most = max(most, lj.weight.shape[1])
    return most


def layer_bounds(
    chain: Chain,
    ball: Ball,
    prior: list[tuple[torch.Tensor, torch.Tensor]] | None = None,
    give_up: float = 1.0,
) -> tuple[list[tuple[torch.Tensor, torch.Tensor]], list[Relax]]:
    """Bounds (l, u) on every hidden pre-activation over the balls, and their relaxations.

    ``prior``: bounds valid for balls at least as large (intersected with the new ones).
    ``give_up``: once more than this fraction of a window's neurons in a layer is
    unstable, its deeper layers keep their interval bounds (sound, loose, cheap):
    such a ball is too large to certify anyway.
    """
    bounds: list[tuple[torch.Tensor, torch.Tensor]] = []
    relaxes: list[Relax] = []
    nb = len(ball.z0)
    hopeful = torch.ones(nb, dtype=torch.bool)
    for i in range(len(chain.layers) - 1):
        shape = _shape(chain, i)
        if i == 0:
            lo = torch.full((nb, *shape), -math.inf)
            hi = torch.full((nb, *shape), math.inf)
        else:  # one step of interval arithmetic from the previous layer's bounds
            pl, pu = bounds[-1]
            hl, hu = pl.clamp(min=0), pu.clamp(min=0)
            mid = _affine(chain.layers[i], (hl + hu) / 2)
            rad = _affine_abs(chain.layers[i], (hu - hl) / 2)
            lo, hi = (mid - rad).reshape(nb, *shape), (mid + rad).reshape(nb, *shape)
        if prior is not None:
            lo, hi = torch.maximum(lo, prior[i][0]), torch.minimum(hi, prior[i][1])
        todo = (((lo < 0) & (hi > 0)).flatten(1) & hopeful[:, None]).nonzero()
        if len(todo):
            per_row = 2 * _patch_floats(chain, i)
            step = max(1, CHUNK_FLOATS // per_row)
            flat_lo, flat_hi = lo.flatten(1), hi.flatten(1)
            for s in range(0, len(todo), step):
                win, neuron = todo[s : s + step, 0], todo[s : s + step, 1]
                value, norm = _backward(chain, i, _start(chain, i, win, neuron, 2), relaxes, ball)
                bound = value - ball.eps[win, None] * norm
                flat_lo[win, neuron] = torch.maximum(flat_lo[win, neuron], bound[:, 0])
                flat_hi[win, neuron] = torch.minimum(flat_hi[win, neuron], -bound[:, 1])
        bounds.append((lo, hi))
        relaxes.append(Relax.of(lo, hi))
        hopeful &= ((lo < 0) & (hi > 0)).flatten(1).float().mean(1) <= give_up
    return bounds, relaxes


def margin_form(
    chain: Chain, ball: Ball, relaxes: list[Relax]
) -> tuple[torch.Tensor, torch.Tensor]:
    """The margin's linear lower bound at x0 and its dual norm: f >= value - eps * norm."""
    nb = len(ball.z0)
    last = len(chain.layers) - 1
    win = torch.arange(nb)
    start = _start(chain, last, win, torch.zeros(nb, dtype=torch.long), 1)
    value, norm = _backward(chain, last, start, relaxes, ball)
    return value[:, 0], norm[:, 0]


# ---------------------------------------------------------------- radius search


@dataclass(frozen=True)
class CertifyConfig:
    """Settings of the radius search (docs/cnn.md, "Certified lower bounds")."""

    steps: int = 4  #: bound propagations per window
    seed: float = 0.05  #: first radius tried, as a fraction of the upper bracket (attack payoff)
    start: float = 0.05  #: first radius tried when no upper bracket is known
    batch: int = 32  #: windows propagated together
    give_up: float = 0.7  #: unstable fraction of a layer beyond which a ball is abandoned


def certified_radius(
    chain: Chain,
    windows: np.ndarray,
    upper: np.ndarray | None = None,
    cfg: CertifyConfig | None = None,
) -> np.ndarray:
    """Per window, an L2 radius within which the margin stays positive (0 when it is not).

    ``upper``: a known flipping radius per window (the attack's payoff, ``inf``
    when none): the search stays below it and starts at ``cfg.seed`` times it.
    It only steers the search; every returned radius is certified on its own.
    """
    cfg = cfg or CertifyConfig()
    n = len(windows)
    out = np.zeros(n)
    with torch.no_grad():
        for a in range(0, n, cfg.batch):
            x = torch.from_numpy(np.ascontiguousarray(windows[a : a + cfg.batch], np.float32))
            up = None if upper is None else np.asarray(upper[a : a + cfg.batch], float)
            out[a : a + len(x)] = _search(chain, x, up, cfg)
    return out


def _search(
    chain: Chain, x: torch.Tensor, upper: np.ndarray | None, cfg: CertifyConfig
) -> np.ndarray:
    """Geometric bisection towards the fixed point r*(R) = R; keeps the best min(R, r*(R))."""
    nb = len(x)
    z0 = _centre(chain, x)
    d = int(np.prod(chain.in_shape))
    f0 = margin_of(chain, x)
    best = torch.zeros(nb, dtype=torch.float64)
    lo = torch.zeros(nb, dtype=torch.float64)
    hi = torch.full((nb,), math.inf, dtype=torch.float64)
    r = torch.full((nb,), cfg.start, dtype=torch.float64)
    if upper is not None:
        u = torch.from_numpy(upper)
        known = torch.isfinite(u) & (u > 0)
        hi = torch.where(known, u, hi)
        r = torch.where(known, cfg.seed * u, r)
    live = f0 > 0
    # bounds of the smallest ball that failed so far: valid for every smaller ball
    prior: list[tuple[torch.Tensor, torch.Tensor]] | None = None
    prior_r = torch.full((nb,), math.inf, dtype=torch.float64)
    for _ in range(cfg.steps):
        if not bool(live.any()):
            break
        idx = live.nonzero().ravel()
        ball = Ball(z0[idx], r[idx].float(), d, chain.subtract_mean)
        pri = None
        if prior is not None:
            inside = r[idx] <= prior_r[idx]
            pri = [
                (_where(inside, pl[idx], -math.inf), _where(inside, pu[idx], math.inf))
                for pl, pu in prior
            ]
        bounds, relaxes = layer_bounds(chain, ball, pri, cfg.give_up)
        value, norm = margin_form(chain, ball, relaxes)
        value, norm = value.double(), norm.double()
        rstar = torch.where(value > 0, value / norm.clamp(min=1e-30), torch.zeros_like(value))
        ri = r[idx]
        best[idx] = torch.maximum(best[idx], torch.minimum(ri, rstar))
        failed = rstar < ri
        # r* decreases with R: the fixed point lies in [r*, R] after a failure, else in [R, r*]
        lo[idx] = torch.maximum(lo[idx], torch.where(failed, rstar, ri))
        hi[idx] = torch.minimum(hi[idx], torch.where(failed, ri, rstar))
        if bool(failed.any()):
            if prior is None:
                prior = [
                    (
                        torch.full((nb, *bl.shape[1:]), -math.inf),
                        torch.full((nb, *bl.shape[1:]), math.inf),
                    )
                    for bl, _ in bounds
                ]
            fidx = idx[failed]
            for (pl, pu), (bl, bu) in zip(prior, bounds, strict=True):
                pl[fidx], pu[fidx] = bl[failed], bu[failed]
            prior_r[fidx] = ri[failed]
        l, h = lo[idx], hi[idx]
        r[idx] = torch.where(
            torch.isfinite(h), torch.sqrt(torch.clamp(l, min=1e-3 * h) * h), 2 * ri
        )
        live[idx] = ~torch.isfinite(h) | (h - l > 0.02 * h)
    result: np.ndarray = (best * (1 - SAFETY)).numpy()
    return result


def _where(keep: torch.Tensor, t: torch.Tensor, other: float) -> torch.Tensor:
    return torch.where(keep.view(-1, *[1] * (t.dim() - 1)), t, torch.full_like(t, other))
