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
:func:`_crown_layer`); the final radius is reduced by ``SAFETY`` (relative) to absorb float32
rounding (not a formally verified floating-point bound).
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
from torch.nn import functional as F

from lesmc.perception.chain import Chain, Conv, Dense, Layer, affine, centred, margin_of
from lesmc.perception.heap import kept_heap
from lesmc.perception.threads import all_torch_threads

SAFETY = 1e-3  #: relative reduction of every certified radius (float32 rounding)
CHUNK_FLOATS = 1 << 23  #: coefficients in flight per propagation chunk (32 MiB of float32)
#: Conv layers from this index on get CROWN by position, every channel at once (_crown_layer).
GROUPED_FROM = 2
#: Local transposed convolutions to fewer channels than this stack STACK patches a sample.
STACK_BELOW, STACK = 8, 4


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


def _affine_abs(layer: Layer, r: torch.Tensor) -> torch.Tensor:
    if isinstance(layer, Conv):
        return F.conv2d(r, layer.weight.abs(), None, layer.stride, layer.padding)
    return F.linear(r.flatten(1), layer.weight.abs())


def _interval_step(
    layer: Layer, lower: torch.Tensor, upper: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Interval bounds of ``layer(ReLU(y))`` from bounds ``lower <= y <= upper`` (IBP)."""
    hl, hu = lower.clamp(min=0), upper.clamp(min=0)
    mid = affine(layer, (hl + hu) / 2)
    rad = _affine_abs(layer, (hu - hl) / 2)
    return mid - rad, mid + rad


def interval_margin(chain: Chain, ball: Ball) -> torch.Tensor:
    """A lower bound on the margin over each ball: exact first layer, then interval steps.

    Looser than CROWN (``layer_bounds`` + ``margin_form``) but a few forward
    passes, and differentiable in the weights of a ``chain_of(..., detach=False)``:
    the robust loss of certified training (benchmarks/exp_certified_training.py).
    """
    lo, hi = _first_layer(chain, ball)
    for layer in chain.layers[1:]:
        lo, hi = _interval_step(layer, lo, hi)
    return lo[:, 0]


# ---------------------------------------------------------------- relaxations


@dataclass
class Relax:
    """Per window and neuron, the lines replacing ReLU(y) on [l, u].

    ``lo * y <= ReLU(y) <= up * y + cut``; ``maps`` holds (lo, up - lo, cut) with
    the channels last: (B, H, W, 3, C) for a convolution's maps, (B, 3, F) for a
    dense layer's.
    """

    maps: torch.Tensor

    @staticmethod
    def of(lower: torch.Tensor, upper: torch.Tensor) -> Relax:
        """CROWN's lines: the chord above, ``y`` or 0 below (whichever is closer)."""
        lower, upper = lower.movedim(1, -1), upper.movedim(1, -1)
        active = lower >= 0
        unstable = (lower < 0) & (upper > 0)
        den = torch.where(unstable, upper - lower, torch.ones_like(upper))
        up = torch.where(unstable, upper / den, active.to(upper.dtype))
        cut = torch.where(unstable, -lower * upper / den, torch.zeros_like(upper))
        lo = torch.where(unstable, (upper > -lower).to(upper.dtype), active.to(upper.dtype))
        return Relax(torch.stack([lo, up - lo, cut], dim=-2))


@dataclass
class Ball:
    """The windows' centres (mean removed when the chain does) and radii."""

    z0: torch.Tensor  # (B, C, H, W)
    eps: torch.Tensor  # (B,)
    d: int  # input dimension
    subtract_mean: bool


def _relu_back(
    a: torch.Tensor, const: torch.Tensor, lines: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Coefficients on h = ReLU(y) -> on y, for a lower bound (a >= 0 takes the lower line).

    ``a`` (T, n, *s): T sets of rows (a neuron's lower and upper bound) sharing the
    relaxation of window row n; ``lines`` = (lo, up - lo, cut), each (n, *s).
    """
    lo, gap, cut = lines
    neg = a.clamp(max=0)
    const = const + (neg * cut).flatten(2).sum(2)
    return torch.addcmul(a * lo, neg, gap), const


def _lines(maps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(lo, up - lo, cut) of relaxation maps (..., 3, C), each (..., C)."""
    lo, gap, cut = maps.unbind(-2)
    return lo, gap, cut


def _conv_back_local(
    a: torch.Tensor, const: torch.Tensor, layer: Conv
) -> tuple[torch.Tensor, torch.Tensor]:
    """Patch coefficients on y = conv(h) + b -> on h: a patch (r-1)s + k wide, no padding.

    ``a`` (T, n, r, r, C) channels last, the layout oneDNN's transposed convolution
    runs fastest in (2x NCHW's on these small patches).
    """
    t, n = a.shape[:2]
    const = const + a.sum(dim=(2, 3)) @ layer.bias
    out = _transpose_conv(a.flatten(0, 1), layer.weight, layer.stride)
    return out.reshape(t, n, *out.shape[1:]), const


def _transpose_conv(x: torch.Tensor, weight: torch.Tensor, stride: int) -> torch.Tensor:
    """The transposed convolution of patches ``x`` (N, r, r, C), channels last, no padding.

    oneDNN's cost on such small maps is mostly per sample when the output has few
    channels (the first layer's: the input's 4): there, every :data:`STACK` patches
    go as one sample, side by side on the channel axis, through a block-diagonal
    weight. 4x the multiplications, by zeros, in 0.6-0.93x the time (docs/performance.md,
    sixteenth round; a grouped convolution, ``groups=STACK``, was no faster). The same
    sums, plus exact zeros: on the shipped N_dr the radii came out bit for bit equal.
    """
    n, r, _, c = x.shape
    c_out = weight.shape[1]
    if c_out >= STACK_BELOW or n < STACK:
        out = F.conv_transpose2d(x.permute(0, 3, 1, 2), weight, stride=stride)
        return out.permute(0, 2, 3, 1)  # a channels-last view, no copy
    if n % STACK:
        x = torch.cat([x, x.new_zeros(-n % STACK, r, r, c)])
    m = len(x) // STACK
    side = x.reshape(m, STACK, r, r, c).permute(0, 2, 3, 1, 4).reshape(m, r, r, STACK * c)
    wide = weight.new_zeros(STACK * c, STACK * c_out, *weight.shape[2:])
    for k in range(STACK):
        wide[k * c : (k + 1) * c, k * c_out : (k + 1) * c_out] = weight
    out = F.conv_transpose2d(side.permute(0, 3, 1, 2), wide, stride=stride).permute(0, 2, 3, 1)
    size = out.shape[1]
    out = out.reshape(m, size, size, STACK, c_out).permute(0, 3, 1, 2, 4)
    return out.reshape(m * STACK, size, size, c_out)[:n]


def _back_full(
    a: torch.Tensor, const: torch.Tensor, layer: Layer, below: tuple[int, ...]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Whole-level coefficients (T, n, *shape), channels last, on y = layer(h) -> on h
    (``below``: h's shape, channels first as the network has it)."""
    t, n = a.shape[:2]
    if isinstance(layer, Dense):
        const = const + a @ layer.bias
        return _channels_last(a @ layer.weight, below), const
    const = const + a.sum(dim=(2, 3)) @ layer.bias
    size = (layer.out_hw - 1) * layer.stride - 2 * layer.padding + layer.weight.shape[-1]
    out = F.conv_transpose2d(
        a.flatten(0, 1).permute(0, 3, 1, 2),  # a channels-last view, no copy
        layer.weight,
        stride=layer.stride,
        padding=layer.padding,
        output_padding=layer.in_hw - size,
    ).permute(0, 2, 3, 1)
    return out.reshape(t, n, *out.shape[1:]), const


def _channels_last(rows: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """Rows (T, n, prod(shape)) over a level in the network's order (channels first) as
    (T, n, *shape) with the channels last (a dense level: unchanged)."""
    a = rows.reshape(*rows.shape[:2], *shape)
    return a.movedim(2, -1).contiguous() if len(shape) == 3 else a


@dataclass(frozen=True)
class _Grid:
    """Where a conv neuron's patch lies on a level: top-left ``pos * stride + origin``."""

    r: int
    stride: int
    origin: int
    cells: int  # positions per side (the neuron's layer)

    def back(self, layer: Conv) -> _Grid:
        """The same neuron's patch one conv layer further down."""
        r = (self.r - 1) * layer.stride + layer.weight.shape[-1]
        return _Grid(
            r, self.stride * layer.stride, self.origin * layer.stride - layer.padding, self.cells
        )

    def patches(self, maps: torch.Tensor) -> torch.Tensor:
        """(B * cells^2, r, r, M): every position's patch of ``maps`` (B, H, H, M), zero outside."""
        h = maps.shape[1]
        left = -self.origin
        right = (self.cells - 1) * self.stride + self.origin + self.r - h
        padded = F.pad(maps, (0, 0, left, right, left, right)).contiguous()
        sb, sh, sw, sm = padded.stride()
        view = padded.as_strided(
            (len(maps), self.cells, self.cells, self.r, self.r, maps.shape[-1]),
            (sb, self.stride * sh, self.stride * sw, sh, sw, sm),
        )
        return view.reshape(-1, self.r, self.r, maps.shape[-1])


def _concretise(
    a: torch.Tensor, const: torch.Tensor, z: torch.Tensor, ball: Ball
) -> tuple[torch.Tensor, torch.Tensor]:
    """(a.z0 + c, ||P a||_2) per row for coefficients ``a`` (T, n, *s) on the input (zero
    outside it); ``z`` (n, *s)."""
    value = (a * z).flatten(2).sum(2) + const
    sq = a.square().flatten(2).sum(2)
    if ball.subtract_mean:
        sq = sq - a.flatten(2).sum(2).square() / ball.d
    return value, sq.clamp(min=0).sqrt()


# ---------------------------------------------------------------- layer bounds


def _shape(chain: Chain, i: int) -> tuple[int, ...]:
    """The output shape of layer ``i`` (``-1``: the input)."""
    if i < 0:
        return chain.in_shape
    layer = chain.layers[i]
    if isinstance(layer, Conv):
        return (layer.weight.shape[0], layer.out_hw, layer.out_hw)
    return (layer.weight.shape[0],)


def _first_layer(chain: Chain, ball: Ball) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact bounds of the first layer (linear in x): ``y(x0) -+ eps ||P w||``."""
    layer = chain.layers[0]
    shape = (1, *chain.in_shape)
    ones = torch.ones(shape)
    if isinstance(layer, Conv):
        sq = F.conv2d(ones, layer.weight.square(), None, layer.stride, layer.padding)
        total = F.conv2d(ones, layer.weight, None, layer.stride, layer.padding)
    else:
        sq, total = layer.weight.square().sum(1)[None], layer.weight.sum(1)[None]
    if ball.subtract_mean:
        sq = sq - total.square() / ball.d
    norm = sq.clamp(min=0).sqrt()
    mid = affine(layer, ball.z0)
    rad = ball.eps.view(-1, *[1] * (mid.dim() - 1)) * norm
    return mid - rad, mid + rad


def _conv_views(
    chain: Chain, i: int, relaxes: list[Relax], ball: Ball
) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Every position's patches (channels last), for the neurons of conv layer ``i``: of each
    level's relaxation lines (layers ``i-1`` down to 0; lo, up - lo and cut side by side on
    the last axis), and of the input with an inside-the-image channel."""
    layer = chain.layers[i]
    assert isinstance(layer, Conv)
    grid = _Grid(layer.weight.shape[-1], layer.stride, -layer.padding, layer.out_hw)
    views = []
    for j in range(i - 1, -1, -1):
        views.append(grid.patches(relaxes[j].maps.flatten(3)))  # (B, H, W, 3C)
        below = chain.layers[j]
        assert isinstance(below, Conv)
        grid = grid.back(below)
    inside = torch.ones_like(ball.z0[:, :1])
    return views, grid.patches(torch.cat([ball.z0, inside], dim=1).permute(0, 2, 3, 1))


def _crown_conv(
    chain: Chain,
    i: int,
    views: tuple[list[torch.Tensor], torch.Tensor],
    ball: Ball,
    win: torch.Tensor,
    neuron: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper CROWN bounds of conv neurons ``(win, neuron)`` of layer ``i`` (local form).

    A row's coefficients are a patch of its receptive field (``_Grid``): +W and -W
    of the neuron pass back through each ReLU's lines and transposed convolution,
    side by side, reading the patch tables once.
    """
    layer = chain.layers[i]
    assert isinstance(layer, Conv)
    cells = layer.out_hw
    ch, pos = neuron // (cells * cells), neuron % (cells * cells)
    w = layer.weight.permute(0, 2, 3, 1)[ch]  # (n, k, k, C): channels last
    a = torch.stack([w, -w])
    const = torch.stack([layer.bias[ch], -layer.bias[ch]])
    bound = _conv_rows_back(chain, i, views, ball, win, pos, a, const)
    return bound[0], -bound[1]


def _crown_conv_at(
    chain: Chain,
    i: int,
    views: tuple[list[torch.Tensor], torch.Tensor],
    ball: Ball,
    win: torch.Tensor,
    pos: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper CROWN bounds, each (C_out, n), of every channel of conv layer ``i``
    at positions ``(win, pos)``: the 2 C_out rows of a position share each gather of its
    relaxation lines (:func:`_crown_conv`'s rows, stable channels included)."""
    layer = chain.layers[i]
    assert isinstance(layer, Conv)
    w = layer.weight.permute(0, 2, 3, 1)  # (C_out, k, k, C): channels last
    a = torch.cat([w, -w]).unsqueeze(1).expand(-1, len(pos), *w.shape[1:])
    const = torch.cat([layer.bias, -layer.bias]).unsqueeze(1).expand(-1, len(pos))
    bound = _conv_rows_back(chain, i, views, ball, win, pos, a, const)
    c_out = w.shape[0]
    return bound[:c_out], -bound[c_out:]


def _conv_rows_back(
    chain: Chain,
    i: int,
    views: tuple[list[torch.Tensor], torch.Tensor],
    ball: Ball,
    win: torch.Tensor,
    pos: torch.Tensor,
    a: torch.Tensor,
    const: torch.Tensor,
) -> torch.Tensor:
    """Lower bounds (T, n) of rows ``a`` (T, n, k, k, C) + ``const`` (T, n) on layer ``i``'s
    pre-activations: row set t of column n lies on window ``win[n]``, position ``pos[n]``,
    passed back through each ReLU's lines and transposed convolution to the input."""
    layer = chain.layers[i]
    assert isinstance(layer, Conv)
    at = win * layer.out_hw**2 + pos  # row of the patch tables
    for j, view in zip(range(i - 1, -1, -1), views[0], strict=True):
        patch = view.index_select(0, at)
        a, const = _relu_back(a, const, _lines(patch.reshape(*patch.shape[:-1], 3, -1)))
        below = chain.layers[j]
        assert isinstance(below, Conv)
        a, const = _conv_back_local(a, const, below)
    zm = views[1].index_select(0, at)
    value, norm = _concretise(a * zm[..., -1:], const, zm[..., :-1], ball)
    out: torch.Tensor = value - ball.eps[win] * norm
    return out


def _crown_full(
    chain: Chain,
    i: int,
    relaxes: list[Relax],
    ball: Ball,
    win: torch.Tensor,
    rows: torch.Tensor,
    bias: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(value at x0, dual norm), each (T, n), of ``rows . h_{i-1} + bias`` propagated as
    whole levels: ``rows`` (T, n, ...) in the network's order and ``bias`` (T, n), for
    windows ``win`` (n,). T row sets share a window's relaxation, read once."""
    a = _channels_last(rows, _shape(chain, i - 1))
    const = bias
    for j in range(i - 1, -1, -1):
        a, const = _relu_back(a, const, _lines(relaxes[j].maps[win]))
        a, const = _back_full(a, const, chain.layers[j], _shape(chain, j - 1))
    return _concretise(a, const, ball.z0[win].movedim(1, -1), ball)


def _row_floats(chain: Chain, i: int) -> int:
    """Most floats one row of layer ``i`` carries while propagating (x 3 for the relaxations)."""
    layer = chain.layers[i]
    if isinstance(layer, Dense):
        return 3 * max(math.prod(_shape(chain, j)) for j in range(-1, i))
    grid = _Grid(layer.weight.shape[-1], layer.stride, -layer.padding, layer.out_hw)
    most = 0
    for j in range(i - 1, -1, -1):
        most = max(most, 3 * _shape(chain, j)[0] * grid.r**2)
        below = chain.layers[j]
        assert isinstance(below, Conv)
        grid = grid.back(below)
    return max(most, (chain.in_shape[0] + 1) * grid.r**2)


def layer_bounds(
    chain: Chain,
    ball: Ball,
    prior: list[tuple[torch.Tensor, torch.Tensor]] | None = None,
    give_up: float = 1.0,
) -> tuple[list[tuple[torch.Tensor, torch.Tensor]], list[Relax]]:
    """Bounds (l, u) on every hidden pre-activation over the balls, and their relaxations.

    The first layer's are exact. A deeper neuron first gets one interval step
    from the previous layer's bounds; only those still unstable get CROWN.
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
        layer = chain.layers[i]
        if i == 0:
            lo, hi = _first_layer(chain, ball)
        else:
            lo, hi = _interval_step(layer, *bounds[-1])
        if prior is not None:
            lo, hi = torch.maximum(lo, prior[i][0]), torch.minimum(hi, prior[i][1])
        todo = (((lo < 0) & (hi > 0)).flatten(1) & hopeful[:, None]).nonzero()
        if i > 0 and len(todo):
            _crown_layer(chain, i, relaxes, ball, todo, lo, hi)
        bounds.append((lo, hi))
        relaxes.append(Relax.of(lo, hi))
        hopeful &= ((lo < 0) & (hi > 0)).flatten(1).float().mean(1) <= give_up
    return bounds, relaxes


def _crown_layer(
    chain: Chain,
    i: int,
    relaxes: list[Relax],
    ball: Ball,
    todo: torch.Tensor,
    lo: torch.Tensor,
    hi: torch.Tensor,
) -> None:
    """Tighten ``lo``, ``hi`` (layer ``i``'s bounds, in place) by CROWN for the neurons
    ``todo`` ((window, neuron) rows), in chunks of about CHUNK_FLOATS coefficients.

    Conv layers from :data:`GROUPED_FROM` on are propagated by position (every channel of
    a position with a neuron to do, :func:`_crown_conv_at`): on the shipped N_dr about 90%
    of their neurons are unstable, and the relaxation patches a row reads are several
    times its own size (docs/performance.md, fifteenth round).
    """
    layer = chain.layers[i]
    if isinstance(layer, Conv) and i >= GROUPED_FROM:
        views = _conv_views(chain, i, relaxes, ball)
        c_out, cells = layer.weight.shape[0], layer.out_hw**2
        places = torch.unique(todo[:, 0] * cells + todo[:, 1] % cells)
        step = max(1, CHUNK_FLOATS // (2 * c_out * _row_floats(chain, i)))
        map_lo, map_hi = lo.view(len(lo), c_out, cells), hi.view(len(hi), c_out, cells)
        for s in range(0, len(places), step):
            win, pos = places[s : s + step] // cells, places[s : s + step] % cells
            low, up = _crown_conv_at(chain, i, views, ball, win, pos)
            map_lo[win, :, pos] = torch.maximum(map_lo[win, :, pos], low.T)
            map_hi[win, :, pos] = torch.minimum(map_hi[win, :, pos], up.T)
        return
    flat_lo, flat_hi = lo.flatten(1), hi.flatten(1)
    step = max(1, CHUNK_FLOATS // (2 * _row_floats(chain, i)))
    tables = _conv_views(chain, i, relaxes, ball) if isinstance(layer, Conv) else None
    for s in range(0, len(todo), step):
        win, neuron = todo[s : s + step, 0], todo[s : s + step, 1]
        if tables is not None:
            low, up = _crown_conv(chain, i, tables, ball, win, neuron)
        else:
            w, b = layer.weight[neuron], layer.bias[neuron]
            value, norm = _crown_full(
                chain, i, relaxes, ball, win, torch.stack([w, -w]), torch.stack([b, -b])
            )
            bound = value - ball.eps[win] * norm
            low, up = bound[0], -bound[1]
        flat_lo[win, neuron] = torch.maximum(flat_lo[win, neuron], low)
        flat_hi[win, neuron] = torch.minimum(flat_hi[win, neuron], up)


def margin_form(
    chain: Chain, ball: Ball, relaxes: list[Relax]
) -> tuple[torch.Tensor, torch.Tensor]:
    """The margin's linear lower bound at x0 and its dual norm: f >= value - eps * norm."""
    last = len(chain.layers) - 1
    layer = chain.layers[last]
    nb = len(ball.z0)
    win = torch.arange(nb)
    value, norm = _crown_full(
        chain, last, relaxes, ball, win, layer.weight.expand(1, nb, -1), layer.bias.expand(1, nb)
    )
    return value[0], norm[0]


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
    lo, hi = _first_layer(chain, Ball(z0, torch.ones(len(z0)), _dim(chain), chain.subtract_mean))
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
