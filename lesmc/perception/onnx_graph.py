"""The ``.onnx`` reader: an ONNX graph run node by node in torch (:class:`OnnxNet`, so it
has gradients for DeepFool and PGD), and read as :class:`~lesmc.perception.net_ops.Op` s
for the certified bounds (:func:`_onnx_ops`).

Why not onnx2torch: it would convert ONNX to torch, but it imports torchvision, whose
PyPI wheel does not load beside the pinned torch; the interpreter here covers the
operations of small detection CNNs (:data:`ONNX_OPS`). What a network is to lesmc is
lesmc/perception/graphs.py's, its ops and their builders lesmc/perception/net_ops.py's;
the ``.pt2`` reader is lesmc/perception/pt2_graph.py; a file is opened by its suffix in
lesmc/perception/network_file.py.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from lesmc.common.errors import InputError, Location, UsageError, clipped, exception_line
from lesmc.perception.graphs import ANY_SIZE, DYNAMIC_BATCH, UserNet, refuse_nonfinite
from lesmc.perception.net_ops import Op, Unsupported, arith_op, avgpool_op, batchnorm_op, conv_op


def _onnx() -> Any:
    try:
        import onnx
    except ImportError:
        raise UsageError(
            "reading .onnx files needs the onnx package: pip install 'lesmc[onnx]'"
        ) from None
    return onnx


class OnnxNet(nn.Module):
    """An ONNX graph run node by node with torch operations (so it has gradients)."""

    def __init__(self, model: Any, path: str) -> None:
        super().__init__()
        onnx = _onnx()
        from onnx import numpy_helper

        g = model.graph
        self.path = path
        self.consts: dict[str, torch.Tensor] = {
            i.name: torch.from_numpy(numpy_helper.to_array(i).copy()) for i in g.initializer
        }
        self.nodes = list(g.node)
        for n in self.nodes:
            if n.op_type == "Constant":
                a = next(a for a in n.attribute if a.name == "value")
                self.consts[n.output[0]] = torch.from_numpy(numpy_helper.to_array(a.t).copy())
            elif n.op_type not in ONNX_OPS:
                raise InputError(
                    f"node '{n.name}': the ONNX operation {n.op_type} is not supported by "
                    f"lesmc's ONNX reader (supported: {', '.join(ONNX_OPS)}); export to .pt2 "
                    "instead",
                    Location(path),
                )
        self.attrs = [
            {a.name: onnx.helper.get_attribute_value(a) for a in n.attribute} for n in self.nodes
        ]
        for n, at in zip(self.nodes, self.attrs, strict=True):
            if n.op_type == "Conv" and (
                at.get("group", 1) != 1 or any(d != 1 for d in at.get("dilations", [1, 1]))
            ):
                raise InputError(
                    f"node '{n.name}': Conv with groups or dilations is not supported by lesmc's "
                    "ONNX reader; export to .pt2 instead",
                    Location(path),
                )
        inputs = [i.name for i in g.input if i.name not in self.consts]
        if len(inputs) != 1 or len(g.output) != 1:
            raise InputError("the network must have one input and one output", Location(path))
        self.input, self.output = inputs[0], g.output[0].name
        _refuse_unordered(self.nodes, {*self.consts, self.input}, self.output, path)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        env: dict[str, torch.Tensor] = dict(self.consts)
        env[self.input] = x
        for n, at in zip(self.nodes, self.attrs, strict=True):
            if n.op_type == "Constant":
                continue
            ins = [env[i] if i else None for i in n.input]
            try:
                env[n.output[0]] = _run(n.op_type, ins, at)
            except Exception as exc:  # a shape the graph was not exported for, ...
                shapes = ", ".join(str(tuple(i.shape)) for i in ins if i is not None)
                raise InputError(
                    f"node '{clipped(n.name or n.output[0], 80)}' ({n.op_type}) fails on "
                    f"inputs of shapes {shapes}: {exception_line(exc)}",
                    Location(self.path),
                ) from None
        return env[self.output]


def _refuse_unordered(nodes: list[Any], known: set[str], output: str, path: str) -> None:
    """Every node's inputs must come before it (ONNX keeps nodes in topological order;
    a cycle breaks it), and the graph's output must be made by a node."""
    made = set(known)
    for n in nodes:
        for i in n.input:
            if i and i not in made:
                raise InputError(
                    f"node '{clipped(n.name or n.output[0], 80)}' ({n.op_type}): its input "
                    f"'{clipped(i, 80)}' is made by no node before it (an ONNX graph lists "
                    "its nodes in order, without cycles)",
                    Location(path),
                )
        made.update(o for o in n.output if o)
    if output not in made:
        raise InputError(
            f"the graph's output '{clipped(output, 80)}' is made by no node", Location(path)
        )


def _run(op: str, ins: list[Any], at: dict[str, Any]) -> Any:
    """One ONNX node on torch tensors (the operation is one of :data:`ONNX_OPS`, checked
    when the graph was read)."""
    return _ONNX_RUN[op](ins[0], ins, at)


def _axes(ins: list[Any], at: dict[str, Any]) -> list[int] | None:
    """A node's axes: an attribute (older opsets) or its second input (newer ones)."""
    if "axes" in at:
        return list(at["axes"])
    return ins[1].tolist() if len(ins) > 1 and ins[1] is not None else None


def _conv_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    pads = at.get("pads", [0, 0, 0, 0])
    h = F.pad(x, (pads[1], pads[3], pads[0], pads[2])) if any(pads) else x
    h = h.contiguous(memory_format=torch.channels_last)  # oneDNN's fast layout (cnn.py)
    return F.conv2d(h, ins[1], ins[2] if len(ins) > 2 else None, at.get("strides", [1, 1]))


def _gemm_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    a = x.t() if at.get("transA", 0) else x
    w = ins[1].t() if at.get("transB", 0) else ins[1]
    y = at.get("alpha", 1.0) * (a @ w)
    return y + at.get("beta", 1.0) * ins[2] if len(ins) > 2 and ins[2] is not None else y


def _reshape_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    shape = [int(v) for v in ins[1].tolist()]
    keep = not at.get("allowzero", 0)  # 0 means "this dimension as it is"
    return x.reshape([x.shape[i] if v == 0 and keep else v for i, v in enumerate(shape)])


def _pool_node(x: Any, ins: list[Any], at: dict[str, Any], average: bool) -> Any:
    k, s = at["kernel_shape"], at.get("strides", [1, 1])
    pads = at.get("pads", [0, 0, 0, 0])
    if not average:
        return F.max_pool2d(x, k, s, (pads[0], pads[1]))
    include = bool(at.get("count_include_pad", 0))
    return F.avg_pool2d(x, k, s, (pads[0], pads[1]), count_include_pad=include)


def _gather_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    axis, idx = at.get("axis", 0), ins[1].long()
    if idx.dim() == 0:
        return x.select(axis, int(idx))
    picked = torch.index_select(x, axis, idx.reshape(-1))
    return picked.reshape(*x.shape[:axis], *idx.shape, *x.shape[axis + 1 :])


def _unsqueeze_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    for a in sorted(_axes(ins, at) or []):
        x = x.unsqueeze(a)
    return x


def _slice_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    starts, ends = ins[1].tolist(), ins[2].tolist()
    axes = ins[3].tolist() if len(ins) > 3 and ins[3] is not None else list(range(len(starts)))
    steps = ins[4].tolist() if len(ins) > 4 and ins[4] is not None else [1] * len(starts)
    where: list[Any] = [slice(None)] * x.dim()
    for a, st, en, sp in zip(axes, starts, ends, steps, strict=True):
        where[a] = slice(st, min(en, x.shape[a]), sp)
    return x[tuple(where)]


def _squeeze_node(x: Any, ins: list[Any], at: dict[str, Any]) -> Any:
    axes = _axes(ins, at)
    return x.squeeze(tuple(axes)) if axes is not None else x.squeeze()


_ONNX_RUN: dict[str, Callable[[Any, list[Any], dict[str, Any]], Any]] = {
    "Relu": lambda x, ins, at: F.relu(x),
    "Sigmoid": lambda x, ins, at: torch.sigmoid(x),
    "Tanh": lambda x, ins, at: torch.tanh(x),
    "Transpose": lambda x, ins, at: x.permute(*at.get("perm", range(x.dim())[::-1])),
    "Concat": lambda x, ins, at: torch.cat([i for i in ins if i is not None], dim=at["axis"]),
    "Identity": lambda x, ins, at: x,
    "Add": lambda x, ins, at: x + ins[1],
    "Sub": lambda x, ins, at: x - ins[1],
    "Mul": lambda x, ins, at: x * ins[1],
    "Div": lambda x, ins, at: x / ins[1],
    "MatMul": lambda x, ins, at: x @ ins[1],
    "Flatten": lambda x, ins, at: torch.flatten(x, at.get("axis", 1)),
    "ReduceMean": lambda x, ins, at: x.mean(
        dim=_axes(ins, at), keepdim=bool(at.get("keepdims", 1))
    ),
    "BatchNormalization": lambda x, ins, at: F.batch_norm(
        x, ins[3], ins[4], ins[1], ins[2], False, 0.0, at.get("epsilon", 1e-5)
    ),
    "Conv": _conv_node,
    "Gemm": _gemm_node,
    "Reshape": _reshape_node,
    "AveragePool": lambda x, ins, at: _pool_node(x, ins, at, average=True),
    "MaxPool": lambda x, ins, at: _pool_node(x, ins, at, average=False),
    "Gather": _gather_node,
    "Squeeze": _squeeze_node,
    "Unsqueeze": _unsqueeze_node,
    "Slice": _slice_node,
}
#: The ONNX operations :class:`OnnxNet` runs (constants are read when the graph is).
ONNX_OPS = ("Constant", *sorted(_ONNX_RUN))


def from_onnx(path: str) -> UserNet:
    """An ``.onnx`` file as a :class:`~lesmc.perception.graphs.UserNet`: run by
    :class:`OnnxNet`, read as ops for the certified bounds (network_file.py opens it)."""
    onnx = _onnx()
    try:
        model = onnx.load(path, load_external_data=False)
    except Exception as exc:
        raise InputError(f"not an ONNX model ({exc})", Location(path)) from None
    for init in model.graph.initializer:
        if init.data_location == onnx.TensorProto.EXTERNAL:
            raise InputError(
                f"initializer '{init.name}' is stored in another file; lesmc reads only the "
                "files it is given: export with external_data=False",
                Location(path),
            )
    try:
        net = OnnxNet(model, path)
    except InputError:
        raise
    except Exception as exc:  # onnx raises its own errors for malformed tensors
        raise InputError(f"cannot read the ONNX graph ({exc})", Location(path)) from None
    dims = next(i for i in model.graph.input if i.name == net.input).type.tensor_type.shape.dim
    shape = [d.dim_value if d.HasField("dim_value") else None for d in dims]
    if len(shape) != 4 or shape[1] is None or (shape[2] is None) != (shape[3] is None):
        raise InputError(
            f"the input must be (batch, C, H, W), C fixed, H and W both fixed or both dynamic; "
            f"got {shape}",
            Location(path),
        )
    if shape[0] is not None:
        raise InputError(
            f"the batch dimension is fixed at {shape[0]}: {DYNAMIC_BATCH}", Location(path)
        )
    refuse_nonfinite(net.consts.items(), path)
    try:
        ops: list[Op] | Unsupported = _onnx_ops(net)
    except Unsupported as exc:
        ops = exc
    c = int(shape[1])
    h, w = (ANY_SIZE, ANY_SIZE) if shape[2] is None else (int(shape[2]), int(shape[3] or 0))
    return UserNet(path, net, (c, h, w), ops, net.output)


def _onnx_ops(net: OnnxNet) -> list[Op]:
    consts = net.consts
    data = net.input
    ops: list[Op] = []
    mean_of: str | None = None
    for n, at in zip(net.nodes, net.attrs, strict=True):
        if n.op_type == "Constant":
            continue
        srcs = [i for i in n.input if i and i not in consts]
        name, op = n.name or n.output[0], n.op_type
        if op == "ReduceMean" and srcs == [data]:
            axes = at.get("axes", consts[n.input[1]].tolist() if len(n.input) > 1 else None)
            if sorted(axes or []) in ([1, 2, 3], [-3, -2, -1]) and at.get("keepdims", 1):
                mean_of = n.output[0]
                continue
        if op == "Sub" and mean_of is not None and srcs == [data, mean_of] and not ops:
            ops.append(Op("center", name, op))
        elif srcs != [data]:
            raise Unsupported(name, op, " (not on a single data path)")
        else:
            ops.append(_onnx_op(name, op, [consts.get(i) for i in n.input], at))
        data = n.output[0]
    return ops


def _onnx_op(name: str, op: str, c: list[torch.Tensor | None], at: dict[str, Any]) -> Op:
    if op == "Relu":
        return Op("relu", name, op)
    if op == "Identity":
        return Op("identity", name, op)
    if op == "Conv":
        w = c[1]
        assert w is not None
        pads = at.get("pads", [0, 0, 0, 0])
        if at.get("group", 1) != 1 or any(d != 1 for d in at.get("dilations", [1, 1])):
            raise Unsupported(name, op, " with groups or dilations")
        if len(set(pads)) != 1:
            raise Unsupported(name, op, " with uneven padding")
        return conv_op(
            name,
            op,
            w,
            c[2] if len(c) > 2 else None,
            list(at.get("strides", [1, 1])),
            [pads[0], pads[0]],
        )
    if op == "Gemm":
        w = c[1]
        assert w is not None
        if at.get("transA", 0):
            raise Unsupported(name, op, " with transA")
        w = w if at.get("transB", 0) else w.t()
        alpha, beta = at.get("alpha", 1.0), at.get("beta", 1.0)
        b = c[2] if len(c) > 2 and c[2] is not None else torch.zeros(w.shape[0])
        return Op("linear", name, op, {"weight": alpha * w, "bias": beta * b.reshape(-1)})
    if op == "MatMul":
        w = c[1]
        assert w is not None
        return Op("linear", name, op, {"weight": w.t(), "bias": torch.zeros(w.shape[1])})
    if op == "Flatten" and at.get("axis", 1) == 1:
        return Op("flatten", name, op)
    if op == "Reshape" and c[1] is not None and len(c[1].reshape(-1)) == 2:
        return Op("flatten", name, op)  # (batch, features): checked against the forward pass
    if op in ("Add", "Sub", "Mul", "Div"):
        k = c[1] if c[1] is not None else c[0]
        if k is None or (op in ("Sub", "Div") and c[1] is None):
            raise Unsupported(name, op, " with a non-constant operand")
        return arith_op(name, op, op.lower(), k)
    if op == "BatchNormalization":
        return batchnorm_op(name, op, c[1], c[2], c[3], c[4], float(at.get("epsilon", 1e-5)))
    if op == "AveragePool":
        pads = at.get("pads", [0, 0, 0, 0])
        return avgpool_op(
            name,
            op,
            list(at["kernel_shape"]),
            list(at.get("strides", [1, 1])),
            [pads[0], pads[2]] if any(pads) else [0, 0],
        )
    raise Unsupported(name, op)
