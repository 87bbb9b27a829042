"""The pieces of linear bound propagation (CROWN) that pass a bound back one layer.

A lower bound on a neuron is a linear function of the level below, ``a . h + c``; the
steps here take it down one level at a time: through a ReLU's two lines
(:class:`Relax`, :func:`relu_back`), through a convolution in *local* form (a
neuron's coefficients live in its receptive field only: :func:`conv_back_local`, on
the patches :class:`Grid` cuts out) or through a whole level (:func:`back_full`);
:func:`concretise` takes its minimum over the L2 :class:`Ball` at the input. The
layer bounds that use them are lesmc/perception/crown.py's; the radius search,
lesmc/perception/certify.py's (whose docstring has the method).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.nn import functional as F

from lesmc.perception.chain import Conv, Dense, Layer

#: Local transposed convolutions to fewer channels than this stack STACK patches a sample.
STACK_BELOW, STACK = 8, 4


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


def relu_back(
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


def relax_lines(maps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(lo, up - lo, cut) of relaxation maps (..., 3, C), each (..., C)."""
    lo, gap, cut = maps.unbind(-2)
    return lo, gap, cut


def conv_back_local(
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


def back_full(
    a: torch.Tensor, const: torch.Tensor, layer: Layer, below: tuple[int, ...]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Whole-level coefficients (T, n, *shape), channels last, on y = layer(h) -> on h
    (``below``: h's shape, channels first as the network has it)."""
    t, n = a.shape[:2]
    if isinstance(layer, Dense):
        const = const + a @ layer.bias
        return channels_last(a @ layer.weight, below), const
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


def channels_last(rows: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """Rows (T, n, prod(shape)) over a level in the network's order (channels first) as
    (T, n, *shape) with the channels last (a dense level: unchanged)."""
    a = rows.reshape(*rows.shape[:2], *shape)
    return a.movedim(2, -1).contiguous() if len(shape) == 3 else a


@dataclass(frozen=True)
class Grid:
    """Where a conv neuron's patch lies on a level: top-left ``pos * stride + origin``."""

    r: int
    stride: int
    origin: int
    cells: int  # positions per side (the neuron's layer)

    def back(self, layer: Conv) -> Grid:
        """The same neuron's patch one conv layer further down."""
        r = (self.r - 1) * layer.stride + layer.weight.shape[-1]
        return Grid(
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


def concretise(
    a: torch.Tensor, const: torch.Tensor, z: torch.Tensor, ball: Ball
) -> tuple[torch.Tensor, torch.Tensor]:
    """(a.z0 + c, ||P a||_2) per row for coefficients ``a`` (T, n, *s) on the input (zero
    outside it); ``z`` (n, *s)."""
    value = (a * z).flatten(2).sum(2) + const
    sq = a.square().flatten(2).sum(2)
    if ball.subtract_mean:
        sq = sq - a.flatten(2).sum(2).square() / ball.d
    return value, sq.clamp(min=0).sqrt()
