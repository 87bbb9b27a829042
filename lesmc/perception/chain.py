"""A network as the bound propagation sees it: a chain of convolutions and dense layers.

The types here are shared by the folding of a user network's ops (ops_to_chain.py),
which builds a :class:`Chain` from a file, and by the certification (certify.py), which propagates
bounds through one; :func:`margin_of` is the chain's own forward pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.nn import functional as F


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


def margin_of(chain: Chain, x: torch.Tensor) -> torch.Tensor:
    """The margin of ``chain`` on a batch (B, C, H, W): the network's own forward pass."""
    h = centred(chain, x)
    for i, layer in enumerate(chain.layers):
        h = affine(layer, h)
        if i + 1 < len(chain.layers):
            h = torch.relu(h)
    return h[:, 0]


def centred(chain: Chain, x: torch.Tensor) -> torch.Tensor:
    """The input as the chain's first layer sees it (minus its mean, where the chain says)."""
    return x - x.mean(dim=(1, 2, 3), keepdim=True) if chain.subtract_mean else x


def affine(layer: Layer, h: torch.Tensor) -> torch.Tensor:
    """One layer's affine map, before its ReLU."""
    if isinstance(layer, Conv):
        return F.conv2d(h, layer.weight, layer.bias, layer.stride, layer.padding)
    return F.linear(h.flatten(1), layer.weight, layer.bias)
