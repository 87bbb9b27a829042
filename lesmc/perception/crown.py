"""Bounds on every hidden pre-activation of a chain over L2 balls, and the margin's bound.

:func:`layer_bounds` bounds each layer in turn: the first exactly (it is linear in the
input), a deeper neuron first by one interval step from the layer below, and only
those still unstable by CROWN (a bound passed back to the input through
lesmc/perception/relaxations.py's steps), conv layers from :data:`GROUPED_FROM` on by
position. :func:`margin_form` is the margin's linear lower bound; :func:`interval_margin`
the cheaper, differentiable interval bound of certified training. The radius search
that calls them is lesmc/perception/certify.py (whose docstring has the method).
"""

from __future__ import annotations

import math

import torch
from torch.nn import functional as F

from lesmc.perception.chain import Chain, Conv, Dense, Layer, affine
from lesmc.perception.relaxations import (
    Ball,
    Grid,
    Relax,
    back_full,
    channels_last,
    concretise,
    conv_back_local,
    relax_lines,
    relu_back,
)

CHUNK_FLOATS = 1 << 23  #: coefficients in flight per propagation chunk (32 MiB of float32)
#: Conv layers from this index on get CROWN by position, every channel at once (_crown_layer).
GROUPED_FROM = 2


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
    lo, hi = first_layer(chain, ball)
    for layer in chain.layers[1:]:
        lo, hi = _interval_step(layer, lo, hi)
    return lo[:, 0]


def _shape(chain: Chain, i: int) -> tuple[int, ...]:
    """The output shape of layer ``i`` (``-1``: the input)."""
    if i < 0:
        return chain.in_shape
    layer = chain.layers[i]
    if isinstance(layer, Conv):
        return (layer.weight.shape[0], layer.out_hw, layer.out_hw)
    return (layer.weight.shape[0],)


def first_layer(chain: Chain, ball: Ball) -> tuple[torch.Tensor, torch.Tensor]:
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
    grid = Grid(layer.weight.shape[-1], layer.stride, -layer.padding, layer.out_hw)
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

    A row's coefficients are a patch of its receptive field (``Grid``): +W and -W
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
        a, const = relu_back(a, const, relax_lines(patch.reshape(*patch.shape[:-1], 3, -1)))
        below = chain.layers[j]
        assert isinstance(below, Conv)
        a, const = conv_back_local(a, const, below)
    zm = views[1].index_select(0, at)
    value, norm = concretise(a * zm[..., -1:], const, zm[..., :-1], ball)
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
    a = channels_last(rows, _shape(chain, i - 1))
    const = bias
    for j in range(i - 1, -1, -1):
        a, const = relu_back(a, const, relax_lines(relaxes[j].maps[win]))
        a, const = back_full(a, const, chain.layers[j], _shape(chain, j - 1))
    return concretise(a, const, ball.z0[win].movedim(1, -1), ball)


def _row_floats(chain: Chain, i: int) -> int:
    """Most floats one row of layer ``i`` carries while propagating (x 3 for the relaxations)."""
    layer = chain.layers[i]
    if isinstance(layer, Dense):
        return 3 * max(math.prod(_shape(chain, j)) for j in range(-1, i))
    grid = Grid(layer.weight.shape[-1], layer.stride, -layer.padding, layer.out_hw)
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
            lo, hi = first_layer(chain, ball)
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
