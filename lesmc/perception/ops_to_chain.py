"""A detector's ops folded into the ``Chain`` of the bound propagation (certify.py).

:func:`chain_of_ops` composes the linear steps between ReLUs exactly: an affine op or
an average pool is folded into the layer before it or, after a ReLU or at the input,
into the next one. :class:`Layers` gathers the layers as ops arrive (heatmap_crop.py
builds a crop's chain with it too).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from lesmc.perception.chain import Chain, Conv, Dense
from lesmc.perception.net_ops import Op, Unsupported


def chain_of_ops(ops: list[Op], in_shape: tuple[int, int, int], t: float) -> Any:
    """The certify.py ``Chain`` of a detector given as ops, with margin ``logit_1 − logit_0 − t``.

    Linear steps between ReLUs are composed exactly: an ``affine`` after a layer
    scales and shifts that layer's outputs, one at the input or after a ReLU is
    moved into the next layer (if that is a convolution, only when it has no
    padding: zero padding does not commute with a shift); an ``avgpool`` is a
    convolution of its own, composed with the layer before it, or with the next
    one when it follows a ReLU.
    """
    built = Layers(channels=in_shape[0], hw=in_shape[1])
    for i, op in enumerate(ops):
        if op.kind == "center" and i != 0:
            raise Unsupported(op.node, op.op, " (mean subtraction only first)")
        built.add(op)
    if built.pending:
        raise Unsupported(
            built.pending[0].node, built.pending[0].op, " (after the last linear layer)"
        )
    layers, relu_after = built.layers, built.relu_after
    last = layers[-1] if layers else None
    if not isinstance(last, Dense) or last.weight.shape[0] != 2 or relu_after[-1]:
        raise Unsupported(
            ops[-1].node if ops else "-",
            ops[-1].op if ops else "-",
            " (a detector must end in a linear layer with two logits)",
        )
    if not all(relu_after[:-1]):
        bad = ops[-1]
        raise Unsupported(
            bad.node, bad.op, " (every layer but the last must be followed by a ReLU)"
        )
    w, b = last.weight, last.bias
    layers[-1] = Dense((w[1] - w[0])[None], (b[1] - b[0] - t)[None])
    return Chain(in_shape, built.subtract_mean, tuple(layers))


@dataclass
class Layers:
    """The chain's layers as ops arrive: linear ops wait in ``pending`` for the next layer
    when no layer without its ReLU precedes them (:func:`chain_of_ops`; heatmap_crop.py
    builds a crop's chain with it too)."""

    channels: int
    hw: int
    layers: list[Any] = field(default_factory=list)
    relu_after: list[bool] = field(default_factory=list)
    pending: list[Op] = field(default_factory=list)
    subtract_mean: bool = False
    flat: bool = False

    def add(self, op: Op) -> None:
        if op.kind == "identity":
            return
        if op.kind == "center":
            self.subtract_mean = True
        elif op.kind == "relu":
            if not self.layers or self.relu_after[-1] or self.pending:
                raise Unsupported(
                    op.node, op.op, " (a ReLU must follow a convolution or a linear layer)"
                )
            self.relu_after[-1] = True
        elif op.kind == "flatten":
            self.flat = True
        elif op.kind in ("affine", "avgpool"):
            if self.layers and not self.relu_after[-1] and not self.pending:
                self.layers[-1], self.hw = _fold_after(self.layers[-1], op, self.hw)
            else:
                self.pending.append(op)
        elif op.kind == "conv":
            self._conv(op)
        elif op.kind == "linear":
            self._linear(op)
        else:
            raise Unsupported(op.node, op.op)

    def _conv(self, op: Op) -> None:
        if self.flat:
            raise Unsupported(op.node, op.op, " after a flatten")
        w, b, s, p = (op.params[k] for k in ("weight", "bias", "stride", "padding"))
        w, b, s, p, hw_in = _fold_before_conv(self.pending, w.float(), b.float(), s, p, self.hw, op)
        out = (hw_in + 2 * p - w.shape[2]) // s + 1
        self._append(Conv(w, b, s, p, hw_in, out))
        self.hw, self.channels = out, w.shape[0]

    def _linear(self, op: Op) -> None:
        w, b = op.params["weight"].float(), op.params["bias"].float()
        w, b = _fold_before_linear(self.pending, w, b, self.channels, self.hw, op)
        self._append(Dense(w, b))
        self.flat = True

    def _append(self, layer: Any) -> None:
        self.layers.append(layer)
        self.relu_after.append(False)
        self.pending = []


def _pool_as_conv(channels: int, k: int) -> torch.Tensor:
    w = torch.zeros(channels, channels, k, k)
    for c in range(channels):
        w[c, c] = 1.0 / (k * k)
    return w


def _compose(w1: torch.Tensor, s1: int, w2: torch.Tensor, s2: int) -> torch.Tensor:
    """The kernel of conv2 (no padding, stride s2) after conv1 (stride s1), no biases."""
    o2, _, k2, _ = w2.shape
    _, c1, k1, _ = w1.shape
    k = k1 + (k2 - 1) * s1
    out = torch.zeros(o2, c1, k, k, dtype=torch.float64)
    a, b = w1.double(), w2.double()
    for u in range(k2):
        for v in range(k2):
            # conv2 tap (u, v) reads conv1's output at offset (u, v)·s1
            out[:, :, u * s1 : u * s1 + k1, v * s1 : v * s1 + k1] += torch.einsum(
                "om,mi...->oi...", b[:, :, u, v], a
            )
    return out.float()


def _fold_after(layer: Any, op: Op, hw: int) -> tuple[Any, int]:
    """``op`` applied to ``layer``'s output, composed into the layer."""
    if op.kind == "affine":
        scale, shift = op.params["scale"].float(), op.params["shift"].float()
        n = layer.weight.shape[0]
        sc, sh = _per_output(scale, n, op), _per_output(shift, n, op)
        shape = (-1,) + (1,) * (layer.weight.dim() - 1)
        w = layer.weight * sc.reshape(shape)
        b = layer.bias * sc + sh
        if isinstance(layer, Conv):
            return Conv(w, b, layer.stride, layer.padding, layer.in_hw, layer.out_hw), hw
        return Dense(w, b), hw
    if not isinstance(layer, Conv):
        raise Unsupported(op.node, op.op, " after a linear layer")
    k, s = op.params["kernel"], op.params["stride"]
    w = _compose(layer.weight, layer.stride, _pool_as_conv(layer.weight.shape[0], k), s)
    out = (layer.out_hw - k) // s + 1
    return Conv(w, layer.bias.clone(), layer.stride * s, layer.padding, layer.in_hw, out), out


def _per_output(v: torch.Tensor, n: int, op: Op) -> torch.Tensor:
    flat = v.reshape(-1)
    if flat.numel() == 1:
        return flat.expand(n).clone()
    if flat.numel() == n:
        return flat.clone()
    raise Unsupported(op.node, op.op, f" (a constant of {flat.numel()} values for {n} channels)")


def _fold_before_conv(
    pending: list[Op], w: torch.Tensor, b: torch.Tensor, s: int, p: int, hw: int, conv: Op
) -> tuple[torch.Tensor, torch.Tensor, int, int, int]:
    """Linear ops between a ReLU (or the input) and a convolution, moved into it."""
    for op in reversed(pending):
        if p:
            raise Unsupported(op.node, op.op, f" before the padded convolution '{conv.node}'")
        if op.kind == "affine":
            c = w.shape[1]
            sc, sh = (
                _per_output(op.params["scale"].float(), c, op),
                _per_output(op.params["shift"].float(), c, op),
            )
            b = b + (w * sh[None, :, None, None]).sum(dim=(1, 2, 3))
            w = w * sc[None, :, None, None]
        else:  # avgpool before a convolution without padding
            k, ps = op.params["kernel"], op.params["stride"]
            w = _compose(_pool_as_conv(w.shape[1], k), ps, w, s)
            s = ps * s
    return w, b, s, p, hw


def _fold_before_linear(
    pending: list[Op], w: torch.Tensor, b: torch.Tensor, channels: int, hw: int, lin: Op
) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear ops between a ReLU (or the input) and a linear layer, moved into it."""
    for op in reversed(pending):
        if op.kind == "affine":
            n = w.shape[1]
            sc = op.params["scale"].float()
            sh = op.params["shift"].float()
            per = n // max(channels, 1) if sc.numel() == channels and channels > 1 else 1
            sc_full = (
                sc.reshape(-1).repeat_interleave(per)
                if sc.numel() > 1
                else sc.reshape(-1).expand(n)
            )
            sh_full = (
                sh.reshape(-1).repeat_interleave(per)
                if sh.numel() > 1
                else sh.reshape(-1).expand(n)
            )
            if sc_full.numel() != n or sh_full.numel() != n:
                raise Unsupported(op.node, op.op, f" before the linear layer '{lin.node}'")
            b = b + w @ sh_full
            w = w * sc_full[None, :]
        else:
            k, s = op.params["kernel"], op.params["stride"]
            out = (hw - k) // s + 1
            if w.shape[1] != channels * out * out:
                raise Unsupported(op.node, op.op, f" before the linear layer '{lin.node}'")
            pool = torch.zeros(channels * out * out, channels * hw * hw)
            for c in range(channels):
                for y in range(out):
                    for x in range(out):
                        row = (c * out + y) * out + x
                        for dy in range(k):
                            for dx in range(k):
                                pool[row, (c * hw + y * s + dy) * hw + x * s + dx] = 1.0 / (k * k)
            w = w @ pool
            hw = out
    return w, b
