"""The user's detector networks: ``.pt2`` (torch.export) and ``.onnx`` files.

A network file replaces one of the shipped CNNs (``--detector`` for N_dr,
``--locator`` for N_lp). lesmc feeds it the windows it feeds its own (docs/cnn.md):

* detector: (B, m+1, 21, 21) in [0, 1] -> (B, 2) logits, index 1 = vehicle;
* locator: (B, m+1, 45, 45) in [0, 1] -> (B, 15, 15) map of vehicle centres in [0, 1].

Two views of a file are built:

* a torch module for the forward pass and its gradients (DeepFool, PGD): the
  exported program itself for ``.pt2``; for ``.onnx`` a small interpreter of the
  graph in torch (:class:`OnnxNet`);
* for certified bounds (detectors only), the network as a sequence of
  :class:`Op` s, which :func:`chain_of_ops` turns into the ``Chain`` of the bound
  propagation (certify.py). A node it cannot express is reported by name.

Why not the libraries: ``torch.export.load`` unpickles parts of the archive
(its docstring says so), and lesmc never unpickles a file, so :func:`load_pt2`
reads the archive itself, refusing any pickled payload, and hands the parsed
graph and raw weights to torch's deserializer. onnx2torch would convert ONNX to
torch, but it imports torchvision, whose PyPI wheel does not load beside the
pinned torch; the interpreter here covers the operations of small detection CNNs.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from lesmc.common.errors import InputError, Location, UsageError, clipped
from lesmc.perception.chain import Chain, Conv, Dense, margin_of


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


#: ``UserNet.in_shape``'s height and width for an ONNX network exported with dynamic H and W
#: (a fully convolutional detector reads frames of any size; docs/detectors.md).
ANY_SIZE = 0


@dataclass
class UserNet:
    """A network loaded from a file: its module, input shape, and its certification view."""

    path: str
    module: nn.Module
    in_shape: tuple[int, int, int]  #: (C, H, W); H = W = ANY_SIZE: dynamic in the file
    ops: list[Op] | Unsupported
    #: the name of its output in the file (ONNX: the graph's; .pt2: the exported program's)
    output: str = ""

    def certifiable_ops(self) -> list[Op]:
        """The ops, or :class:`Unsupported` naming the node that has none."""
        if isinstance(self.ops, Unsupported):
            raise self.ops
        return self.ops

    def chain(self, t: float) -> Any:
        """The detector as the bound propagation sees it (margin threshold ``t``), checked
        against its own forward pass; an unsupported node is an InputError naming it."""
        try:
            chain = chain_of_ops(self.certifiable_ops(), self.in_shape, t)
        except Unsupported as exc:
            raise InputError(
                f"{exc}; payoffs from attacks still work (drop --certify, or --payoffs attack)",
                Location(self.path),
            ) from None
        same_margin(self, chain, t)
        return chain


def same_margin(net: UserNet, chain: Any, t: float) -> None:
    """The chain must compute the network's own margin (a guard against a reading of the
    file's graph that differs from its forward pass): on 64 random windows, to float32
    rounding."""
    x = torch.rand(64, *net.in_shape, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        logits = net.module(x)
        want = logits[:, 1] - logits[:, 0] - t
    got = margin_of(chain, x)
    if not torch.allclose(got, want, rtol=1e-3, atol=1e-3 * float(want.abs().max()) + 1e-4):
        raise InputError(
            "certified bounds: lesmc's reading of the network's graph does not compute its "
            f"forward pass (largest difference {float((got - want).abs().max()):.3g}); "
            "payoffs from attacks still work",
            Location(net.path),
        )


def load_network(path: str | Path) -> UserNet:
    """A ``.pt2`` or ``.onnx`` network file (by its suffix)."""
    p = str(path)
    if not Path(p).is_file():
        raise InputError("no such network file", Location(p))
    if p.endswith(".pt2"):
        return _from_pt2(p)
    if p.endswith(".onnx"):
        return _from_onnx(p)
    raise InputError(
        "a network file must be a torch.export archive (.pt2) or ONNX (.onnx)", Location(p)
    )


def check_network(net: UserNet, role: str, channels: int, size: int, out: tuple[int, ...]) -> None:
    """The network must take lesmc's windows for its role and answer each with ``out``
    (detector (2,) logits, locator (15, 15) maps), in finite numbers: :func:`probe`."""
    want = (channels, size, size)
    if net.in_shape != want:
        c, h, w = net.in_shape
        size_text = "any height and width" if h == ANY_SIZE else f"{h}x{w}"
        raise InputError(
            f"the {role} takes inputs of {c} channels of {size_text}; lesmc's {role} windows "
            f"are {channels} channels (the m = {channels - 1} previous frames and the current "
            f"one) of {size}x{size} (docs/own-system.md)",
            Location(net.path),
        )
    probe(net, role, out)


#: Windows in the probe batch: more than one, so a batch fixed at 1 inside the graph fails.
PROBE_BATCH = 3


def probe(net: UserNet, role: str, out: tuple[int, ...]) -> None:
    """Run the network once on :data:`PROBE_BATCH` random windows before the video: it
    must run, give one ``out``-shaped answer per window, and finite numbers (a NaN or
    infinite answer would silently accept or reject every window)."""
    x = torch.rand(PROBE_BATCH, *net.in_shape, generator=torch.Generator().manual_seed(0))
    where = Location(net.path)
    y = answer(net, x, role)
    want = (PROBE_BATCH, *out)
    if not isinstance(y, torch.Tensor) or tuple(y.shape) != want:
        got = tuple(y.shape) if isinstance(y, torch.Tensor) else type(y).__name__
        shape = ", ".join(["B", *map(str, out)])
        meaning = {
            "detector": "two logits, index 1 = vehicle",
            "locator": "a map of vehicle centres",
        }
        raise InputError(
            f"the {role} must answer a batch of B windows with ({shape}): "
            f"{meaning.get(role, '')}; on {PROBE_BATCH} windows it gave {got} "
            "(docs/own-system.md)",
            where,
        )
    refuse_nonfinite_answer(net, y, role)


def answer(net: UserNet, x: torch.Tensor, role: str) -> Any:
    """The network's answer to the probe batch ``x``; whatever the graph raises (a reshape
    to a fixed batch, ...) is an InputError naming the file."""
    try:
        with torch.no_grad():
            return net.module(x)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(
            f"the {role} fails on a batch of {len(x)} inputs: {_first_line(exc)}",
            Location(net.path),
        ) from None


def refuse_nonfinite_answer(net: UserNet, y: torch.Tensor, role: str) -> None:
    """A NaN or infinite answer to the probe batch is an InputError naming the file."""
    bad = int((~torch.isfinite(y)).sum())
    if bad:
        raise InputError(
            f"the {role} gives NaN or infinite outputs ({bad} of {y.numel()} on "
            f"{PROBE_BATCH} random inputs)",
            Location(net.path),
        )


def _first_line(exc: BaseException) -> str:
    """An exception's message as one line of a user's error (torch's run to many)."""
    lines = str(exc).strip().splitlines()
    return clipped(f"{type(exc).__name__}: {lines[0] if lines else ''}", 300)


def refuse_nonfinite(tensors: Iterable[tuple[str, torch.Tensor]], path: str) -> None:
    """A weight or constant holding NaN or infinity makes every answer NaN or infinite:
    refused, named."""
    for name, t in tensors:
        if isinstance(t, torch.Tensor) and t.is_floating_point():
            bad = int((~torch.isfinite(t)).sum())
            if bad:
                raise InputError(
                    f"weight '{clipped(name, 80)}' holds {bad} NaN or infinite value"
                    f"{'s' if bad > 1 else ''} (of {t.numel()})",
                    Location(path),
                )


#: What lesmc asks of a batch dimension (.pt2 and .onnx alike).
DYNAMIC_BATCH = "export with dynamic_shapes=({0: torch.export.Dim('batch')},) (docs/own-system.md)"


# ---------------------------------------------------------------- .pt2


def load_pt2(path: str) -> Any:
    """An ExportedProgram read without unpickling: every weight and constant must be a
    raw tensor payload (torch.export.save writes them so), the sample inputs are skipped."""
    pkg: Any = importlib.import_module("torch.export.pt2_archive._package")
    from torch._export.serde import schema
    from torch._export.serde.serialize import ExportedProgramDeserializer, _bytes_to_dataclass

    try:
        reader = pkg.PT2ArchiveReader(path)
        names = reader.get_file_names()
    except Exception as exc:  # torch raises RuntimeError for a bad zip, OSError, ...
        raise InputError(f"not a torch.export archive ({exc})", Location(path)) from None
    models = [
        n[len(pkg.MODELS_DIR) : -len(".json")]
        for n in names
        if n.startswith(pkg.MODELS_DIR) and n.endswith(".json")
    ]
    if len(models) != 1:
        raise InputError(f"expected one exported program, found {len(models)}", Location(path))
    name = models[0]
    for legacy in (f"{pkg.WEIGHTS_DIR}{name}.pt", f"{pkg.CONSTANTS_DIR}{name}.pt"):
        if legacy in names:
            raise InputError("a legacy (pickled) archive: export it again", Location(path))
    for fmt in (pkg.WEIGHTS_CONFIG_FILENAME_FORMAT, pkg.CONSTANTS_CONFIG_FILENAME_FORMAT):
        config = pkg._load_payload_config(reader, fmt.format(name))
        for fqn, meta in config.config.items():
            raw = meta.path_name.startswith(
                (pkg.WEIGHT_FILENAME_PREFIX, pkg.TENSOR_CONSTANT_FILENAME_PREFIX)
            )
            if meta.use_pickle or not raw:
                raise InputError(
                    f"'{fqn}' is stored pickled; lesmc never unpickles a file (export plain "
                    "tensors)",
                    Location(path),
                )
    try:
        program = _bytes_to_dataclass(
            schema.ExportedProgram, reader.read_bytes(pkg.MODELS_FILENAME_FORMAT.format(name))
        )
        state = pkg._load_state_dict(reader, name)
        constants = pkg._load_constants(reader, name)
        return ExportedProgramDeserializer().deserialize(program, state, constants, None)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"cannot read the exported program ({exc})", Location(path)) from None


def _from_pt2(path: str) -> UserNet:
    ep = load_pt2(path)
    sig = ep.graph_signature
    if len(sig.user_inputs) != 1:
        raise InputError(
            f"the network must take one input (the window), it takes {len(sig.user_inputs)}",
            Location(path),
        )
    node = next(n for n in ep.graph.nodes if n.op == "placeholder" and n.name == sig.user_inputs[0])
    shape = tuple(node.meta["val"].shape)
    if len(shape) != 4 or not all(isinstance(d, int) for d in shape[1:]):
        raise InputError(f"the input must be (batch, C, H, W), got {shape}", Location(path))
    if isinstance(shape[0], int):
        raise InputError(
            f"the batch dimension is fixed at {shape[0]}: {DYNAMIC_BATCH}", Location(path)
        )
    refuse_nonfinite([*ep.state_dict.items(), *ep.constants.items()], path)
    module = ep.module()
    try:
        ops: list[Op] | Unsupported = _fx_ops(ep)
    except Unsupported as exc:
        ops = exc
    out = sig.user_outputs[0] if len(sig.user_outputs) == 1 else ""
    return UserNet(path, _Frozen(module, path), (shape[1], shape[2], shape[3]), ops, out)


class _Frozen(nn.Module):
    """A loaded module whose weights are constants (no gradients for them); an error of
    its forward pass is an InputError naming the file and the batch's shape."""

    def __init__(self, inner: nn.Module, path: str) -> None:
        super().__init__()
        self.inner = inner
        self.path = path
        for p in inner.parameters():
            p.requires_grad_(False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        try:
            out: torch.Tensor = self.inner(x)
        except Exception as exc:  # the exported program's guards and shape errors
            raise InputError(
                f"the network fails on inputs of shape {tuple(x.shape)}: {_first_line(exc)}",
                Location(self.path),
            ) from None
        return out


def _fx_ops(ep: Any) -> list[Op]:
    """The ops of an exported program's graph (aten operations, one data path)."""
    sig = ep.graph_signature
    tensors: dict[str, torch.Tensor] = {}
    for ph, fqn in sig.inputs_to_parameters.items():
        tensors[ph] = ep.state_dict[fqn].detach()
    for ph, fqn in sig.inputs_to_buffers.items():
        tensors[ph] = (
            ep.state_dict.get(fqn) if fqn in ep.state_dict else ep.constants[fqn]
        ).detach()
    for ph, fqn in sig.inputs_to_lifted_tensor_constants.items():
        tensors[ph] = ep.constants[fqn].detach()
    data = sig.user_inputs[0]
    ops: list[Op] = []
    mean_of: str | None = None
    for n in ep.graph.nodes:
        if n.op in ("placeholder", "output"):
            continue
        name, target = n.name, str(n.target).removeprefix("aten.")
        args = list(n.args)
        srcs = [a.name for a in args if hasattr(a, "name") and a.name not in tensors]
        if target == "mean.dim" and srcs == [data] and list(args[1]) in ([1, 2, 3], [-3, -2, -1]):
            mean_of = name
            continue
        if target == "sub.Tensor" and mean_of is not None and srcs == [data, mean_of] and not ops:
            ops.append(Op("center", name, target))
        elif len(srcs) != 1 or srcs[0] != data:
            raise Unsupported(name, target, " (not on a single data path)")
        else:
            ops.append(_fx_op(name, target, args, tensors))
        data = name
    return ops


def _const(a: Any, tensors: dict[str, torch.Tensor]) -> torch.Tensor | None:
    if hasattr(a, "name"):
        return tensors.get(a.name)
    if isinstance(a, int | float):
        return torch.tensor(float(a))
    return None


def _fx_op(name: str, target: str, args: list[Any], tensors: dict[str, torch.Tensor]) -> Op:
    def t(i: int) -> torch.Tensor | None:
        return _const(args[i], tensors) if len(args) > i and args[i] is not None else None

    def ints(i: int, default: list[int]) -> list[int]:
        v = args[i] if len(args) > i else default
        return [v, v] if isinstance(v, int) else list(v)

    if target in ("relu.default", "relu_.default"):
        return Op("relu", name, target)
    if target == "conv2d.default":
        w = t(1)
        assert w is not None
        b = t(2)
        if (len(args) > 5 and ints(5, [1, 1]) != [1, 1]) or (len(args) > 6 and args[6] != 1):
            raise Unsupported(name, target, " with dilation or groups")
        return _conv(name, target, w, b, ints(3, [1, 1]), ints(4, [0, 0]))
    if target == "linear.default":
        w, b = t(1), t(2)
        assert w is not None
        return Op(
            "linear",
            name,
            target,
            {"weight": w, "bias": b if b is not None else torch.zeros(w.shape[0])},
        )
    if target == "flatten.using_ints" and list(args[1:]) in ([1], [1, -1], [1, 3]):
        return Op("flatten", name, target)
    if target in ("view.default", "reshape.default") and len(args[1]) == 2:
        return Op("flatten", name, target)  # (batch, features): checked against the forward pass
    if target in ("add.Tensor", "sub.Tensor", "mul.Tensor", "div.Tensor"):
        c = t(1)
        if c is None:
            raise Unsupported(name, target, " with a non-constant operand")
        return _arith(name, target, target.split(".")[0], c)
    if target in ("_native_batch_norm_legit_no_training.default", "batch_norm.default"):
        return _batchnorm(name, target, t(1), t(2), t(3), t(4), float(args[-1]))
    if target == "avg_pool2d.default":
        return _avgpool(name, target, ints(1, [1, 1]), ints(2, ints(1, [1, 1])), ints(3, [0, 0]))
    if target == "getitem" or target.endswith("getitem"):
        return Op("identity", name, target)
    if target in ("contiguous.default", "clone.default"):  # a copy, perhaps in another layout
        return Op("identity", name, target)
    raise Unsupported(name, target.split(".")[0])


def _conv(
    name: str, op: str, w: torch.Tensor, b: torch.Tensor | None, stride: list[int], pad: list[int]
) -> Op:
    if w.shape[2] != w.shape[3] or stride[0] != stride[1] or pad[0] != pad[1]:
        raise Unsupported(name, op, " with non-square kernels, strides or padding")
    bias = b if b is not None else torch.zeros(w.shape[0])
    return Op("conv", name, op, {"weight": w, "bias": bias, "stride": stride[0], "padding": pad[0]})


def _arith(name: str, op: str, how: str, c: torch.Tensor) -> Op:
    """x + c, x − c, x·c or x / c: an affine op (whether c fits is checked when folding)."""
    c = c.float()
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    scale, shift = {
        "add": (one, c),
        "sub": (one, -c),
        "mul": (c, zero),
        "div": (1.0 / c, zero),
    }[how]
    return Op("affine", name, op, {"scale": scale, "shift": shift})


def _batchnorm(name: str, op: str, gamma: Any, beta: Any, mean: Any, var: Any, eps: float) -> Op:
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


def _avgpool(name: str, op: str, k: list[int], s: list[int], pad: list[int]) -> Op:
    if k[0] != k[1] or s[0] != s[1] or pad != [0, 0]:
        raise Unsupported(name, op, " with non-square kernels or padding")
    return Op("avgpool", name, op, {"kernel": k[0], "stride": s[0]})


# ---------------------------------------------------------------- .onnx


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
                    f"inputs of shapes {shapes}: {_first_line(exc)}",
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


def _from_onnx(path: str) -> UserNet:
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
        return _conv(
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
        return _arith(name, op, op.lower(), k)
    if op == "BatchNormalization":
        return _batchnorm(name, op, c[1], c[2], c[3], c[4], float(at.get("epsilon", 1e-5)))
    if op == "AveragePool":
        pads = at.get("pads", [0, 0, 0, 0])
        return _avgpool(
            name,
            op,
            list(at["kernel_shape"]),
            list(at.get("strides", [1, 1])),
            [pads[0], pads[2]] if any(pads) else [0, 0],
        )
    raise Unsupported(name, op)


# ---------------------------------------------------------------- ops -> Chain


def chain_of_ops(ops: list[Op], in_shape: tuple[int, int, int], t: float) -> Any:
    """The certify.py ``Chain`` of a detector given as ops, with margin ``logit_1 − logit_0 − t``.

    Linear steps between ReLUs are composed exactly: an ``affine`` after a layer
    scales and shifts that layer's outputs, one at the input or after a ReLU is
    moved into the next layer (if that is a convolution, only when it has no
    padding: zero padding does not commute with a shift); an ``avgpool`` is a
    convolution of its own, composed with the layer before it, or with the next
    one when it follows a ReLU.
    """
    built = _Layers(channels=in_shape[0], hw=in_shape[1])
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
class _Layers:
    """The chain's layers as ops arrive: linear ops wait in ``pending`` for the next layer
    when no layer without its ReLU precedes them (:func:`chain_of_ops`)."""

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
