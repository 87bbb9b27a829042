"""A user's network as the bound propagation sees it: a sequence of :class:`Op` s.

Both readers (``.pt2``: lesmc/perception/pt2_graph.py, ``.onnx``:
lesmc/perception/onnx_graph.py) turn the nodes of a file into :class:`Op` s with the
builders here (:func:`conv_op`, :func:`arith_op`, :func:`batchnorm_op`,
:func:`avgpool_op`); a node the bound propagation cannot express is
:class:`Unsupported`, named. lesmc/perception/ops_to_chain.py folds the ops into the
``Chain`` that certification propagates bounds through.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch


@dataclass(frozen=True)
class Op:
    """One step of a network as the bound propagation sees it.

    ``kind``: ``center`` (x − mean over C, H, W), ``conv`` (weight, bias, stride,
    padding), ``relu``, ``flatten``, ``linear`` (weight, bias), ``affine``
    (y = scale·x + shift, scale and shift broadcast per channel or scalar),
    ``avgpool`` (kernel, stride). ``node`` and ``op`` name it in the file.
    """

    kind: str
    node: str
    op: str
    params: dict[str, Any] = field(default_factory=dict)


class Unsupported(Exception):
    """A node the bound propagation cannot express: certification is refused, attacks work."""

    def __init__(self, node: str, op: str, why: str = "") -> None:
        super().__init__(f"node '{node}': {op} is not supported by certified bounds{why}")
        self.node, self.op = node, op


def conv_op(
    name: str, op: str, w: torch.Tensor, b: torch.Tensor | None, stride: list[int], pad: list[int]
) -> Op:
    """A convolution's op (square kernel, stride and padding only; no bias: zeros), as
    both readers (``.pt2`` here, ``.onnx`` in onnx_graph.py) build it."""
    if w.shape[2] != w.shape[3] or stride[0] != stride[1] or pad[0] != pad[1]:
        raise Unsupported(name, op, " with non-square kernels, strides or padding")
    bias = b if b is not None else torch.zeros(w.shape[0])
    return Op("conv", name, op, {"weight": w, "bias": bias, "stride": stride[0], "padding": pad[0]})


def arith_op(name: str, op: str, how: str, c: torch.Tensor) -> Op:
    """x + c, x − c, x·c or x / c: an affine op (whether c fits is checked when folding);
    both readers build it."""
    c = c.float()
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    scale, shift = {
        "add": (one, c),
        "sub": (one, -c),
        "mul": (c, zero),
        "div": (1.0 / c, zero),
    }[how]
    return Op("affine", name, op, {"scale": scale, "shift": shift})


def batchnorm_op(name: str, op: str, gamma: Any, beta: Any, mean: Any, var: Any, eps: float) -> Op:
    """An inference batch norm as the affine op it is (running statistics needed; no
    ``gamma``/``beta``: 1/0), as both readers build it."""
    if mean is None or var is None:
        raise Unsupported(name, op, " without running statistics")
    g = gamma if gamma is not None else torch.ones_like(mean)
    bt = beta if beta is not None else torch.zeros_like(mean)
    scale = g / torch.sqrt(var + eps)
    return Op(
        "affine",
        name,
        op,
        {"scale": scale[:, None, None], "shift": (bt - mean * scale)[:, None, None]},
    )


def avgpool_op(name: str, op: str, k: list[int], s: list[int], pad: list[int]) -> Op:
    """An average pool's op (square kernel and stride, no padding), as both readers build it."""
    if k[0] != k[1] or s[0] != s[1] or pad != [0, 0]:
        raise Unsupported(name, op, " with non-square kernels or padding")
    return Op("avgpool", name, op, {"kernel": k[0], "stride": s[0]})
