"""A fully convolutional heatmap network run on a crop of the frame, and bounded there.

A network read from a file has one input size (the ``.pt2`` exported program
guards it), but a fully convolutional one computes a cell from its receptive
field alone. :func:`conv_net` reads the network's operations (net_ops.py and
ops_to_chain.py: the same reading certification uses for window classifiers:
convolutions, ReLUs, batch norms, scalings and average pools folded into the
convolutions) into a :class:`ConvNet`, our own layers, which run on any H x W.

Geometry (one axis; the other is the same). Output cells ``a..b`` read input
pixels ``lo..hi``: backwards through each layer (kernel k, stride s, padding p),
``a -> a·s − p`` and ``b -> b·s − p + k − 1``. A crop ``[y0, y1)`` computes those
cells exactly when ``y0 <= max(lo, 0)`` is a multiple of the total stride (so the
crop's cells line up with the frame's, layer by layer) and ``y1 >= min(hi + 1,
H)``: every value those cells use then comes from the crop's own pixels, and
where the crop meets the frame's edge its zero padding is the frame's. Callers
still check the crop's cells against the whole frame's (:func:`same_cells`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch.nn import functional as F

from lesmc.perception.chain import Chain, Conv, Dense
from lesmc.perception.detector_file import LoadedDetector
from lesmc.perception.net_ops import Unsupported
from lesmc.perception.ops_to_chain import Layers

#: Crop cells and whole-frame cells agree to this (relative to the map's largest value).
SAME_CELLS = 1e-4


@dataclass(frozen=True)
class ConvNet:
    """A heatmap network as convolutions, each but the last followed by a ReLU; the last
    has one output channel, the raw heatmap (a network with size outputs, ``size = "wh"``:
    its last convolution's channel 0; the sizes are not priced or certified)."""

    layers: tuple[Conv, ...]
    in_channels: int

    @property
    def stride(self) -> int:
        """The total stride: one output cell per ``stride`` input pixels."""
        s = 1
        for layer in self.layers:
            s *= layer.stride
        return s

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, h, w) inputs -> (B, h', w') raw cells."""
        h = x
        for i, layer in enumerate(self.layers):
            h = F.conv2d(h, layer.weight, layer.bias, layer.stride, layer.padding)
            if i + 1 < len(self.layers):
                h = torch.relu(h)
        return h[:, 0]

    def reads(self, a: int, b: int) -> tuple[int, int]:
        """The input pixels ``lo..hi`` (inclusive; outside the frame where padding is read)
        that output cells ``a..b`` of one axis depend on."""
        for layer in reversed(self.layers):
            k = layer.weight.shape[2]
            a = a * layer.stride - layer.padding
            b = b * layer.stride - layer.padding + k - 1
        return a, b

    def crop(self, a: int, b: int, size: int) -> tuple[int, int]:
        """``[y0, y1)``: the crop of an axis of ``size`` pixels that computes output cells
        ``a..b`` exactly (module docstring)."""
        lo, hi = self.reads(a, b)
        s = self.stride
        return max(0, lo // s * s), min(size, hi + 1)

    def field(self) -> int:
        """The receptive field's side, in pixels."""
        lo, hi = self.reads(0, 0)
        return hi - lo + 1


def conv_net(det: LoadedDetector) -> ConvNet:
    """``det``'s network as a :class:`ConvNet`; :class:`Unsupported` naming the node that
    does not fit (a flatten, a linear layer, a missing ReLU, an input mean subtracted
    over the whole frame, a total stride other than the detector file's)."""
    ops = det.net.certifiable_ops()
    built = Layers(channels=det.net.in_shape[0], hw=det.height)
    for op in ops:
        if op.kind in ("center", "flatten", "linear"):
            raise Unsupported(op.node, op.op, " in a fully convolutional heatmap network")
        built.add(op)
    last = ops[-1] if ops else None
    where = (last.node, last.op) if last is not None else ("-", "-")
    if built.pending:
        raise Unsupported(built.pending[0].node, built.pending[0].op, " (after the last conv)")
    if not built.layers or built.relu_after[-1] or not all(built.relu_after[:-1]):
        raise Unsupported(
            *where, " (a heatmap network must be convolutions, each but the last followed by "
            "a ReLU)",
        )  # fmt: skip
    layers = tuple(built.layers)
    if layers[-1].weight.shape[0] != 1 and det.spec.size is None:
        raise Unsupported(*where, f" (the last convolution has {layers[-1].weight.shape[0]} "
                          "output channels, not 1)")  # fmt: skip
    last = layers[-1]  # with size = "wh": its channel 0 alone, the score map
    layers = (*layers[:-1], replace(last, weight=last.weight[:1], bias=last.bias[:1]))
    net = ConvNet(layers, det.net.in_shape[0])
    if net.stride != det.spec.stride:
        raise Unsupported(*where, f" (the layers' strides make {net.stride}, the detector "
                          f"file says {det.spec.stride})")  # fmt: skip
    return net


def same_cells(got: torch.Tensor, want: torch.Tensor, scale: float) -> torch.Tensor:
    """(B,) whether each crop's cells ``got`` (B, h, w) equal the whole frame's ``want``."""
    tol = SAME_CELLS * max(scale, 1.0)
    return ((got - want).abs().flatten(1) <= tol).all(dim=1)


def peak_chain(net: ConvNet, side: int, row: int, col: int, t: float) -> Chain:
    """The certify.py chain of cell (``row``, ``col``) of a ``side`` x ``side`` crop:
    margin ``raw − t``. The last convolution at that cell is a dense row over the
    previous layer's (C, h, w) outputs."""
    layers: list[Conv | Dense] = []
    hw = side
    for layer in net.layers:
        k = layer.weight.shape[2]
        out = (hw + 2 * layer.padding - k) // layer.stride + 1
        layers.append(replace(layer, in_hw=hw, out_hw=out))
        hw = out
    last = layers[-1]
    assert isinstance(last, Conv)
    x = torch.zeros(1, last.weight.shape[1], last.in_hw, last.in_hw, requires_grad=True)
    y = F.conv2d(x, last.weight, None, last.stride, last.padding)
    (row_w,) = torch.autograd.grad(y[0, 0, row, col], x)
    layers[-1] = Dense(row_w.reshape(1, -1).detach(), (last.bias[:1] - t).detach().float())
    return Chain((net.in_channels, side, side), False, tuple(layers))
